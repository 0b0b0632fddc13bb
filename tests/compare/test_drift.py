"""Clock drift (uwval.comparison.offset): closed forms from applied stamps and from the motion,
and the stamp conversion that removes it."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from uwval.comparison import compare
from uwval.comparison.offset import (
    drift_from_applied_stamps,
    drift_from_motion,
    remove_drift,
)
from uwval.posestream import PoseStream

F = 50.0


def _motion(t: np.ndarray) -> np.ndarray:
    return np.column_stack(
        [0.4 * np.sin(0.9 * t) + 0.1 * t, 0.3 * np.cos(0.5 * t), 0.05 * np.sin(1.7 * t)]
    )


def _stream(t_s: np.ndarray, pos: np.ndarray, applied: np.ndarray | None = None) -> PoseStream:
    q = np.tile([0.0, 0.0, 0.0, 1.0], (t_s.size, 1))
    return PoseStream.from_arrays(
        np.round(t_s * 1e9).astype(np.int64),
        pos,
        q,
        frame="enu",
        applied_stamp=None if applied is None else np.round(applied * 1e9).astype(np.int64),
    )


def _drifting_pair(
    ppm: float, duration: float = 120.0, latency: float = 0.012
) -> tuple[PoseStream, PoseStream]:
    """Gazebo at 50 Hz; Unity at 60 Hz showing the pose of ``latency`` s earlier, stamped by a
    clock that runs ``ppm`` fast: unity_t = t + ppm 1e-6 t."""
    tg = np.arange(0, duration, 1 / F)
    tu = np.arange(0.5, duration - 0.5, 1 / 60)
    shown = tu - latency
    ref = _stream(tg, _motion(tg))
    other = _stream(tu * (1 + ppm * 1e-6), _motion(shown), applied=shown)
    return ref, other


def test_drift_from_applied_stamps_is_the_slope_of_the_stamp_difference() -> None:
    ref, other = _drifting_pair(50.0)
    fit = drift_from_applied_stamps(ref, other)
    assert fit is not None
    assert fit.source == "applied_stamps"
    # unity_t - applied = latency + 50e-6 t: slope 50e-6 per second of the Unity clock
    assert fit.ppm == pytest.approx(50.0 / (1 + 50e-6), abs=0.05)
    assert fit.significant


def test_drift_from_the_motion_is_the_trend_of_the_windowed_lag() -> None:
    ref, other = _drifting_pair(50.0)
    res = compare(ref, other.with_(applied_stamp=None), drift="auto")
    drift = res.stats["offset"]["drift"]
    assert drift["source"] == "motion"
    assert drift["fitted_ppm"] == pytest.approx(50.0, abs=1.0)
    assert res.stats["offset"]["drift_ppm"] == pytest.approx(50.0, abs=1.0)
    # with the drift removed the lag is the latency again, all along the run
    assert res.stats["lag"]["fitted_s"] == pytest.approx(0.012, abs=5e-4)


def test_without_drift_nothing_is_removed() -> None:
    ref, other = _drifting_pair(0.0)
    res = compare(ref, other, drift="auto")
    assert not res.stats["offset"]["drift"]["removed"]
    assert res.stats["offset"]["drift_ppm"] == 0.0


def test_too_short_a_run_pins_no_drift_from_the_motion() -> None:
    ref, _ = _drifting_pair(50.0, duration=10.0)
    t = (ref.t - ref.t[0]) * 1e-9
    assert drift_from_motion(t, ref.position, ref.position) is None


@settings(max_examples=60, deadline=None)
@given(
    ppm=st.floats(-500.0, 500.0, allow_nan=False),
    start=st.integers(0, 2_000_000_000_000_000_000),
    steps=st.lists(st.integers(1, 10**9), min_size=2, max_size=50),
)
def test_remove_drift_scales_every_interval_and_keeps_the_first_stamp(
    ppm: float, start: int, steps: list[int]
) -> None:
    t = start + np.concatenate(([0], np.cumsum(steps))).astype(np.int64)
    s = PoseStream(
        t=t,
        position=np.zeros((t.size, 3)),
        orientation=np.tile([0.0, 0.0, 0.0, 1.0], (t.size, 1)),
        frame="enu",
    )
    out = remove_drift(s, ppm)
    assert out.t[0] == t[0]
    rel = (t - t[0]).astype(np.float64)
    expected = rel * (1 - ppm * 1e-6)
    # int64 nanoseconds: each stamp within half a nanosecond of the exact conversion
    assert np.all(np.abs((out.t - t[0]).astype(np.float64) - expected) <= 0.5 + 1e-9 * rel)
    assert np.all(np.diff(out.t) > 0)


def test_cli_refuses_an_unknown_drift_mode_in_one_line(tmp_path: Path) -> None:
    from cli_runner import run_uwval

    from uwval.io.tum import write_tum

    ref, other = _drifting_pair(0.0, duration=5.0)
    a, b = tmp_path / "a.tum", tmp_path / "b.tum"
    write_tum(a, ref)
    write_tum(b, other)
    res = run_uwval("compare", a, b, "--drift", "sometimes")
    assert res.returncode != 0
    assert "Traceback" not in res.stderr
    assert "unknown drift mode 'sometimes'" in res.stderr
