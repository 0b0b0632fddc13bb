"""End to end through the CLI: simulate -> TCP bridge -> log -> compare (issue 2, item 9)."""

from __future__ import annotations

from pathlib import Path

import pytest
from cli_runner import compare_json, simulate_log
from cli_runner import run_uwval as uwval


@pytest.fixture(scope="module")
def run_log(tmp_path_factory: pytest.TempPathFactory) -> Path:
    log = tmp_path_factory.mktemp("e2e") / "run.mcap"
    return simulate_log(log)


def test_simulate_then_compare_small_error_high_correlation(run_log: Path) -> None:
    d = compare_json(str(run_log))
    assert d["n_samples"] > 900
    axes = d["axes"]
    assert set(axes) >= {"x", "y", "z", "roll", "pitch", "yaw"}
    # x moves (10 N surge): Unity follows Gazebo with r > 0.99 and a small error, bounded by
    # one render frame plus one idle sleep of the Connector's reader (10 ms) of lag at the
    # terminal speed (~1.27 m/s * (1/60 + 0.01) s ~ 3.4 cm)
    assert axes["x"]["pearson_r"] > 0.99
    assert axes["yaw"]["pearson_r"] > 0.99
    assert axes["x"]["mae"] < 0.02
    assert d["position_error_norm"]["max"] < 0.045
    # z does not move (neutral buoyancy): Pearson r is undefined, and says why
    assert axes["z"]["pearson_r"] is None
    pen = d["position_error_norm"]
    assert set(pen) >= {"mean", "median", "std", "min", "max", "rmse", "sse"}
    assert pen["min"] <= pen["median"] <= pen["max"]


def test_wrong_frame_convention_gives_large_error(run_log: Path) -> None:
    right = compare_json(str(run_log))
    wrong = compare_json(str(run_log), "--frame", "unity-enu")
    assert wrong["position_error_norm"]["rmse"] > 100 * right["position_error_norm"]["rmse"]
    assert wrong["position_error_norm"]["rmse"] > 1.0  # metres: the frames matter


def test_compare_table_is_readable(run_log: Path) -> None:
    res = uwval("compare", str(run_log))
    assert res.returncode == 0, res.stderr
    for word in ("MAE", "RMSE", "x", "yaw", "Pearson"):
        assert word in res.stdout


@pytest.mark.parametrize("fmt", ["rosbag1", "rosbag2"])
def test_other_log_formats_compare_the_same(tmp_path: Path, run_log: Path, fmt: str) -> None:
    out = tmp_path / ("run.bag" if fmt == "rosbag1" else "run_bag2")
    res = uwval(
        "simulate",
        "--force",
        "10,0,0",
        "--torque",
        "0,0,1",
        "--current",
        "0,0.2,0",
        "--duration",
        "20",
        "--format",
        fmt,
        "-o",
        str(out),
    )
    assert res.returncode == 0, res.stderr
    a = compare_json(str(run_log))
    b = compare_json(str(out))
    assert b["n_samples"] == a["n_samples"]
    for axis in ("x", "y", "yaw"):
        assert b["axes"][axis]["mae"] == pytest.approx(a["axes"][axis]["mae"], rel=1e-9)


def test_bad_inputs_are_clean_errors(tmp_path: Path) -> None:
    res = uwval("simulate", "--force", "ten", "-o", str(tmp_path / "x.mcap"))
    assert res.returncode == 2
    assert "--force" in res.stderr
    assert "Traceback" not in res.stderr
    empty = tmp_path / "empty.mcap"
    empty.write_bytes(b"")
    res = uwval("compare", str(empty))
    assert res.returncode == 2
    assert str(empty) in res.stderr.replace("\n", "")
    assert "Traceback" not in res.stderr
