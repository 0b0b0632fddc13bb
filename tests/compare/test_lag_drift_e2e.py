"""Issue 31's done-when, through the CLI on simulated runs: a known injected latency is
recovered from the poses alone, and a 50 ppm clock drift is fitted and removed.

The Unity side is the simulator's real one (link timing, vsync, float32); the tests compare
figures with each other (the lag from the poses against the latency from applied stamps, a
drifting run against the same run without drift), never against today's exact lag."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
from cli_runner import compare_json, run_uwval


def _simulate(path: Path, *extra: str, duration: float = 20.0) -> Path:
    res = run_uwval(
        "simulate",
        "--force",
        "10,2,0",
        "--torque",
        "0,0,1",
        "--current",
        "0.25,0,0",
        "--duration",
        str(duration),
        *extra,
        "-o",
        str(path),
        timeout=300,
    )
    assert res.returncode == 0, res.stderr
    return path


@pytest.fixture(scope="module")
def latency_json(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    log = _simulate(tmp_path_factory.mktemp("lag") / "lat.mcap", "--latency", "0.02")
    return compare_json(str(log))


def test_lag_from_the_poses_matches_the_latency_from_applied_stamps(
    latency_json: dict[str, Any],
) -> None:
    lag = latency_json["lag"]
    measured = latency_json["latency"]["mean_ms"] * 1e-3
    assert measured > 0.02  # the injected 20 ms plus link and frame waits
    # within 10 % (or 3 ms) of the latency the applied stamps measure
    assert abs(lag["fitted_s"] - measured) <= max(0.1 * measured, 0.003)
    # the CI brackets the latency measured at the same samples, weighted as the fit
    lo, hi = lag["ci95_s"]
    assert lo <= lag["measured_s"] <= hi
    assert lag["agrees"] is True


def test_removing_the_lag_leaves_at_most_30_percent_of_the_x_error(
    latency_json: dict[str, Any],
) -> None:
    raw = latency_json["axes"]["x"]["mae"]
    assert latency_json["lag"]["residual"]["x"]["mae"] <= 0.3 * raw
    assert latency_json["lag"]["explained"] > 0.8


def test_the_text_says_the_answer_in_a_sentence(tmp_path: Path) -> None:
    log = _simulate(tmp_path / "short.mcap", "--latency", "0.01", duration=5.0)
    res = run_uwval("compare", str(log))
    assert res.returncode == 0, res.stderr
    assert "Unity shows Gazebo's pose" in res.stdout
    assert "ms late (95 % CI" in res.stdout


@pytest.fixture(scope="module")
def drift_logs(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """One 300 s run with a 50 ppm Unity clock drift, and the same run without drift."""
    d = tmp_path_factory.mktemp("drift")
    drifting = _simulate(d / "drift.mcap", "--unity-clock-drift", "50", duration=300.0)
    steady = _simulate(d / "steady.mcap", "--unity-clock-drift", "0", duration=300.0)
    return drifting, steady


def test_drift_auto_fits_50_ppm_and_removes_it(drift_logs: tuple[Path, Path]) -> None:
    drifting, steady = drift_logs
    fixed = compare_json(str(drifting), "--drift", "auto")
    assert fixed["offset"]["drift_ppm"] == pytest.approx(50.0, abs=5.0)
    assert fixed["offset"]["drift"]["source"] == "applied_stamps"
    base = compare_json(str(steady))
    assert fixed["axes"]["x"]["mae"] == pytest.approx(base["axes"]["x"]["mae"], rel=0.15)


def test_drift_from_the_motion_alone(drift_logs: tuple[Path, Path]) -> None:
    """Without applied stamps (the lag's trend over the run): the library path."""
    from uwval.comparison import compare
    from uwval.io import read_streams

    drifting, _ = drift_logs
    g, u = "/gazebo/model_rov_pose", "/unity/model_rov_pose"
    streams = read_streams(drifting, [g, u])
    other = streams[u].with_(applied_stamp=None)
    res = compare(streams[g], other, drift="auto")
    drift = res.stats["offset"]["drift"]
    assert drift["source"] == "motion"
    assert res.stats["offset"]["drift_ppm"] == pytest.approx(50.0, abs=5.0)


def test_unremoved_drift_on_a_long_run_is_a_warning(drift_logs: tuple[Path, Path]) -> None:
    drifting, steady = drift_logs
    off = compare_json(str(drifting))
    assert off["offset"]["drift_ppm"] == 0.0
    assert any("ppm" in w and "--drift auto" in w for w in off["warnings"])
    # the drift left in doubles the x error by the end of the run: the fit shows it
    assert not any("--drift auto" in w for w in compare_json(str(steady))["warnings"])
