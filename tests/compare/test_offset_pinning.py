"""``--offset auto`` says when the motion cannot pin the offset (issue 32 point 3): it refuses a
constant velocity, warns loudly on a repeating motion, and stays quiet (and right) on real
clocks that differ by an offset."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from cli_runner import run_uwval, simulate_log

from uwval.comparison import compare
from uwval.comparison.offset import estimate_offset
from uwval.errors import AlignmentError
from uwval.posestream import PoseStream

F = 50.0


def _stream(t: np.ndarray, pos: np.ndarray, seed: int, noise: float = 1e-4) -> PoseStream:
    rng = np.random.default_rng(seed)
    q = np.tile([0.0, 0.0, 0.0, 1.0], (t.size, 1))
    return PoseStream.from_arrays(
        np.round(t * 1e9).astype(np.int64), pos + rng.normal(0, noise, pos.shape), q, frame="enu"
    )


def _pair(
    path_of: Callable[[np.ndarray], np.ndarray], shift: float = 3.0
) -> tuple[PoseStream, PoseStream]:
    """Reference on [0, 60) s; the other is the same motion stamped ``shift`` s later."""
    t = np.arange(0, 60, 1 / F)
    return _stream(t, path_of(t), 1), _stream(t + shift, path_of(t), 2)


def _constant_velocity(t: np.ndarray) -> np.ndarray:
    return np.column_stack([0.5 * t, 0.1 * t, 0 * t])


def _circle(t: np.ndarray) -> np.ndarray:
    w = 2 * np.pi / 5.0  # one lap every 5 s
    return np.column_stack([np.sin(w * t), np.cos(w * t), 0 * t])


def _rich(t: np.ndarray) -> np.ndarray:
    return np.column_stack(
        [np.sin(0.7 * t) + 0.3 * np.sin(2.3 * t), 0.1 * t * np.cos(0.4 * t), 0.2 * np.sin(1.1 * t)]
    )


def test_constant_velocity_is_refused() -> None:
    ref, oth = _pair(_constant_velocity)
    with pytest.raises(AlignmentError, match="almost constant velocity"):
        estimate_offset(ref, oth)
    with pytest.raises(AlignmentError, match="give --offset S"):
        compare(ref, oth, offset="auto")


def test_a_repeating_motion_is_a_loud_warning_with_an_honest_uncertainty() -> None:
    ref, oth = _pair(_circle)
    est = estimate_offset(ref, oth)
    assert not est.pinned
    assert "NOT pinned" in (est.note or "")
    # the uncertainty is the distance to the rival offset (a multiple of the 5 s lap)
    assert est.uncertainty >= 4.9
    res = compare(ref, oth, offset="auto")
    assert any("NOT pinned" in w for w in res.warnings)
    assert res.to_json()["offset"]["estimate"]["pinned"] is False


def test_a_rich_motion_is_pinned() -> None:
    ref, oth = _pair(_rich)
    est = estimate_offset(ref, oth)
    assert est.pinned
    assert est.offset == pytest.approx(-3.0, abs=1e-3)
    assert est.uncertainty < 1e-3


def _write_tum(path: Path, t: np.ndarray, pos: np.ndarray) -> Path:
    rows = np.column_stack([t, pos, np.zeros((t.size, 3)), np.ones(t.size)])
    np.savetxt(path, rows, fmt="%.9f")
    return path


def test_cli_refuses_constant_velocity_in_one_line(tmp_path: Path) -> None:
    t = np.arange(0, 60, 1 / F)
    a = _write_tum(tmp_path / "gazebo.tum", t, _constant_velocity(t))
    b = _write_tum(tmp_path / "unity.tum", t + 12.72, _constant_velocity(t))
    res = run_uwval("compare", a, b, "--offset", "auto")
    assert res.returncode != 0
    assert "Traceback" not in res.stderr
    assert "constant velocity" in res.stderr
    assert "--offset S" in res.stderr


@pytest.fixture(scope="module")
def two_clocks(tmp_path_factory: pytest.TempPathFactory) -> tuple[PoseStream, PoseStream]:
    """A simulated run whose Unity clock is 3 s ahead (with 50 ms of link latency); the
    applied stamps are dropped so that only the motion can tell the offset."""
    from uwval.io import read_streams

    log = tmp_path_factory.mktemp("clocks") / "clocks.mcap"
    simulate_log(log, "--unity-clock-offset", "3", "--latency", "0.05")
    g, u = "/gazebo/model_rov_pose", "/unity/model_rov_pose"
    streams = read_streams(log, [g, u])
    return streams[g], streams[u].with_(applied_stamp=None)


def test_real_clocks_with_an_offset_are_pinned_without_a_warning(
    two_clocks: tuple[PoseStream, PoseStream],
) -> None:
    ref, oth = two_clocks
    res = compare(ref, oth, offset="auto")
    est = res.to_json()["offset"]["estimate"]
    assert est["pinned"] is True
    assert est["signal"] == "velocity"
    # 3 s of clock offset plus the mean delay the motion cannot tell from it (50 ms + frames)
    assert -3.1 < est["offset_s"] < -3.05
    assert not any("pinned" in w for w in res.warnings)


def test_a_vehicle_that_only_jitters_in_place_is_refused() -> None:
    """No motion but measurement noise: every offset fits as badly as any other."""
    ref, oth = _pair(lambda t: np.zeros((t.size, 3)))
    with pytest.raises(AlignmentError, match="cannot estimate the clock offset"):
        estimate_offset(ref, oth)
