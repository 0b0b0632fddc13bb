"""Issue 16, one-log workflows: ``uwval check`` and ``uwval report`` on one log, a pair of
trajectory files or a saved ``uwval compare -o`` JSON, with compare's --align/--offset/--sync.
"""

from __future__ import annotations

import json
from pathlib import Path

from cli_runner import run_uwval
from seeded_motion import moving_vehicle

from uwval.io.tum import write_tum
from uwval.io.writers import open_writer, write_stream
from uwval.resources import data_path

THRESHOLDS = data_path("thresholds", "default.toml")

_pose = moving_vehicle


def _log(tmp_path: Path) -> Path:
    log = tmp_path / "run.mcap"
    with open_writer(log) as w:
        write_stream(w, "/gazebo/model_rov_pose", _pose(1), "enu")
        write_stream(w, "/unity/model_rov_pose", _pose(2), "enu")
    return log


def _pair(tmp_path: Path, shift_s: float = 0.0) -> tuple[Path, Path]:
    a, b = tmp_path / "gt.txt", tmp_path / "est.txt"
    write_tum(a, _pose(1))
    write_tum(b, _pose(2, shift_s=shift_s))
    return a, b


def test_check_one_log(tmp_path: Path) -> None:
    p = run_uwval("check", _log(tmp_path), "--thresholds", THRESHOLDS, "--align", "se3")
    assert p.returncode == 0, p.stderr
    assert "PASS (15 values checked)" in p.stdout
    bad = run_uwval("check", _log(tmp_path), "--thresholds", THRESHOLDS, "--align", "affine")
    assert bad.returncode == 2 and "unknown alignment 'affine'" in bad.stderr


def test_check_a_pair_with_compares_options(tmp_path: Path) -> None:
    a, b = _pair(tmp_path, shift_s=1000.0)  # the second clock runs 1000 s ahead
    bad = run_uwval("check", a, b, "--thresholds", THRESHOLDS)
    assert bad.returncode == 2 and "aligned samples" in bad.stderr
    ok = run_uwval(
        "check", a, b, "--offset", "-1000", "--sync", "nearest", "--thresholds", THRESHOLDS
    )
    assert ok.returncode == 0, ok.stderr
    assert "PASS" in ok.stdout


def test_check_a_saved_compare_result(tmp_path: Path) -> None:
    a, b = _pair(tmp_path)
    out = tmp_path / "fr.json"
    assert run_uwval("compare", a, b, "--align", "se3", "-o", out).returncode == 0
    p = run_uwval("check", out, "--thresholds", THRESHOLDS, "--json")
    assert p.returncode == 0, p.stderr
    verdict = json.loads(p.stdout)
    assert verdict["passed"] is True and verdict["checked"] == 15


def test_report_a_saved_compare_result_and_a_pair(tmp_path: Path) -> None:
    a, b = _pair(tmp_path)
    out = tmp_path / "fr.json"
    assert run_uwval("compare", a, b, "-o", out).returncode == 0
    # (no per-run plots here, to keep the test short: test_saved_result_inputs_... checks
    # how a saved result's files are found again for them)
    p = run_uwval("report", out, "-o", tmp_path / "saved.html", "--max-detail-runs", "0")
    assert p.returncode == 0, p.stderr
    assert "(1 run(s)); verdict PASS" in p.stdout
    assert "fr" in (tmp_path / "saved.html").read_text()
    q = run_uwval("report", a, b, "--align", "sim3", "--sync", "nearest", "-o", tmp_path / "p.html")
    assert q.returncode == 0, q.stderr
    assert "verdict PASS" in q.stdout
    assert (tmp_path / "p.html").read_text().count("<img") >= 2  # plots of the pair


def test_one_trajectory_file_alone_is_a_one_line_error(tmp_path: Path) -> None:
    a, _ = _pair(tmp_path)
    p = run_uwval("check", a, "--thresholds", THRESHOLDS)
    assert p.returncode == 2
    assert "give two files" in p.stderr and "Traceback" not in p.stderr


def test_saved_result_inputs_are_recovered_or_dropped(tmp_path: Path) -> None:
    from uwval.cli.report_cmd import _saved_inputs

    a, b = _pair(tmp_path)
    out = tmp_path / "fr.json"
    args = ("compare", a, b, "--sync", "nearest", "-as", "--offset", "0.001", "-o", out)
    assert run_uwval(*args).returncode == 0
    doc = json.loads(out.read_text())
    log, opts = _saved_inputs(doc)
    assert log == a
    assert opts == {
        "sync": "nearest", "offset": 0.001, "align": "sim3", "max_diff": 0.01, "path_b": b
    }  # fmt: skip
    b.unlink()  # a file is gone: no plots, and the report says why
    assert _saved_inputs(doc) == (None, {})
