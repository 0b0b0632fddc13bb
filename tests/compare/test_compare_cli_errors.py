"""``uwval compare`` on the command line: bad options and unwritable outputs are clean one-line
errors (exit 2), a reader warning one clean line; never a traceback."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from cli_runner import run_uwval as _uwval


@pytest.fixture(scope="module")
def run_log(tmp_path_factory: pytest.TempPathFactory) -> Path:
    log = tmp_path_factory.mktemp("rv") / "run.mcap"
    res = _uwval(
        "simulate", "--force", "10,0,0", "--torque", "0,0,1", "--duration", "5", "-o", str(log)
    )
    assert res.returncode == 0, res.stderr
    return log


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        (["--offset", "nan"], "finite"),
        (["--offset", "inf"], "finite"),
        (["--max-gap", "-1"], "max_gap"),
        (["--max-gap", "0"], "max_gap"),
        (["--sync", "nearest", "--max-diff", "-1"], "max_diff"),
        (["--format", "foo"], "unknown input format 'foo'"),
    ],
)
def test_bad_compare_options_are_clean_errors(run_log: Path, args: list[str], needle: str) -> None:
    res = _uwval("compare", str(run_log), *args)
    assert res.returncode == 2, res.stdout + res.stderr
    assert needle in res.stderr
    assert "Traceback" not in res.stderr


def test_compare_output_creates_its_folder_or_fails_cleanly(tmp_path: Path, run_log: Path) -> None:
    out = tmp_path / "new" / "dir" / "result.json"
    res = _uwval("compare", str(run_log), "-o", str(out))
    assert res.returncode == 0, res.stderr
    assert json.loads(out.read_text())["n_samples"] > 0
    blocker = tmp_path / "file"
    blocker.write_text("x")
    res = _uwval("compare", str(run_log), "-o", str(blocker / "x.json"))
    assert res.returncode == 2
    assert "cannot write" in res.stderr
    assert "Traceback" not in res.stderr


def test_truncated_log_warning_is_one_clean_line(tmp_path: Path, run_log: Path) -> None:
    data = run_log.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: int(len(data) * 0.8)])
    res = _uwval("compare", str(cut))
    assert res.returncode == 0, res.stderr
    lines = [ln for ln in res.stderr.splitlines() if "truncated" in ln]
    assert len(lines) == 1  # once, although the file is opened more than once
    assert lines[0].startswith("warning:")
    assert ".py:" not in res.stderr  # not the warnings module's file:line form


def test_streams_on_different_clocks_name_both_time_ranges_and_the_fix(tmp_path: Path) -> None:
    """Two files from different clocks (issue 16): the error gives both time ranges and points
    to --offset auto, which then compares them (the offset recovered from the motion)."""
    from uwval.comparison.synthetic import unity_view, vehicle_motion
    from uwval.io.tum import write_tum

    gazebo = vehicle_motion(1500, 50.0, seed=3)  # 30 s from t = 0
    unity = unity_view(gazebo, convention="enu", clock_offset=1000.0, rate_hz=50.0)
    write_tum(tmp_path / "gazebo.tum", gazebo)
    write_tum(tmp_path / "unity.tum", unity)
    nearest = _uwval("compare", tmp_path / "gazebo.tum", tmp_path / "unity.tum")
    assert nearest.returncode == 2  # evo's association (the default for trajectory files)
    assert "reference spans [0.000000, 29.980000] s, other [1000.000000, " in nearest.stderr
    res = _uwval("compare", tmp_path / "gazebo.tum", tmp_path / "unity.tum", "--sync", "interp")
    assert res.returncode == 2
    message = res.stderr
    assert "Traceback" not in message
    assert "do not overlap in time" in message
    assert "reference [0.000, 29.980] s" in message
    assert "other [1000.000, " in message
    assert "--offset auto" in message
    ok = _uwval(
        "compare", tmp_path / "gazebo.tum", tmp_path / "unity.tum", "--offset", "auto", "--json"
    )
    assert ok.returncode == 0, ok.stderr
    offset = json.loads(ok.stdout)["offset"]
    assert offset["source"] == "auto"
    assert offset["applied_s"] == pytest.approx(-1000.0, abs=0.001)


def test_the_table_header_says_how_the_streams_were_synchronised(tmp_path: Path) -> None:
    """interp and nearest give different numbers (evo uses nearest): the header says which."""
    from uwval.comparison.synthetic import unity_view, vehicle_motion
    from uwval.io.tum import write_tum

    gazebo = vehicle_motion(500, 50.0, seed=4)
    write_tum(tmp_path / "gt.tum", gazebo)
    write_tum(tmp_path / "est.tum", unity_view(gazebo, convention="enu", rate_hz=50.0))
    text = _uwval("compare", tmp_path / "gt.tum", tmp_path / "est.tum", "--sync", "interp")
    assert "(sync interp:" in " ".join(text.stdout.split())
    # two trajectory files: evo's association by default, and the header says so
    text = _uwval("compare", tmp_path / "gt.tum", tmp_path / "est.tum")
    assert "(sync nearest, max diff 0.01 s, as evo)" in " ".join(text.stdout.split())
