"""Issue 16: ``uwval.toml`` names the topic pairs, frames, compare options and thresholds,
so that compare / check / report need no flags; command-line options win over the file."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from cli_runner import run_uwval
from seeded_motion import moving_vehicle

from uwval.config import load_config
from uwval.errors import ConfigError
from uwval.io.tum import write_tum
from uwval.io.writers import open_writer, write_stream
from uwval.resources import data_path

_pose = moving_vehicle


@pytest.fixture
def project(tmp_path: Path) -> Path:
    """A folder with a two-pair log (renamed topics) and a uwval.toml naming the pairs."""
    with open_writer(tmp_path / "run.mcap") as w:
        write_stream(w, "/model/tethys/pose", _pose(1), "enu")
        write_stream(w, "/unity/tethys/pose", _pose(2), "enu")
        write_stream(w, "/model/buoy/pose", _pose(3), "enu")
        write_stream(w, "/unity/buoy/pose", _pose(4), "enu")
    (tmp_path / "ci").mkdir()
    (tmp_path / "ci" / "th.toml").write_bytes(data_path("thresholds", "default.toml").read_bytes())
    (tmp_path / "uwval.toml").write_text(
        """
thresholds = "ci/th.toml"

[compare]
sync = "nearest"
align = "se3"

[[pair]]
name = "tethys"
reference = "/model/tethys/pose"
other = "/unity/tethys/pose"

[[pair]]
reference = "/model/buoy/pose"
other = "/unity/buoy/pose"
frame = "enu"
"""
    )
    return tmp_path


def test_compare_without_flags_uses_the_project_file(project: Path) -> None:
    p = run_uwval("compare", "run.mcap", "--json", cwd=project)
    assert p.returncode == 0, p.stderr
    doc = json.loads(p.stdout)
    assert doc["primary_topic"] == "tethys"
    assert list(doc["topics"]) == ["tethys", "buoy/pose"]
    assert doc["sync"]["method"] == "nearest" and doc["alignment"]["mode"] == "se3"
    # the command line wins over the file
    q = run_uwval(
        "compare", "run.mcap", "--json", "--sync", "interp", "--align", "sim3", cwd=project
    )
    qd = json.loads(q.stdout)
    assert qd["sync"]["method"] == "interp" and qd["alignment"]["mode"] == "sim3"
    # topics given: the file's pairs are not used, its options still are
    r = run_uwval(
        "compare", "run.mcap", "--gazebo-topic", "/model/buoy/pose", "--unity-topic",
        "/unity/buoy/pose", "--json", cwd=project,
    )  # fmt: skip
    rd = json.loads(r.stdout)
    assert list(rd["topics"]) == ["buoy/pose"] and rd["sync"]["method"] == "nearest"


def test_config_option_names_another_file(
    project: Path, tmp_path_factory: pytest.TempPathFactory
) -> None:
    elsewhere = tmp_path_factory.mktemp("elsewhere")
    p = run_uwval(
        "compare", project / "run.mcap", "--config", project / "uwval.toml", "--json", cwd=elsewhere
    )
    assert p.returncode == 0, p.stderr
    assert json.loads(p.stdout)["primary_topic"] == "tethys"
    missing = run_uwval("compare", project / "run.mcap", "--config", elsewhere / "nope.toml")
    assert (
        missing.returncode == 2 and "nope.toml: no such project file (--config)" in missing.stderr
    )


def test_check_and_report_take_pairs_and_thresholds_from_the_file(project: Path) -> None:
    p = run_uwval("check", "run.mcap", cwd=project)  # no --thresholds: uwval.toml names them
    assert p.returncode == 0, p.stderr
    assert "PASS (30 values checked)" in p.stdout  # 15 per pair, both pairs
    q = run_uwval("report", "run.mcap", "-o", "r.html", "--max-detail-runs", "0", cwd=project)
    assert q.returncode == 0, q.stderr
    assert "verdict PASS" in q.stdout
    html = (project / "r.html").read_text()
    assert "ci/th.toml" in html and "tethys" in html


def test_two_files_use_the_files_compare_options(tmp_path: Path) -> None:
    write_tum(tmp_path / "gt.txt", _pose(1))
    write_tum(tmp_path / "est.txt", _pose(2, shift_s=100.0))
    (tmp_path / "uwval.toml").write_text('[compare]\noffset = -100\nsync = "nearest"\n')
    p = run_uwval("compare", "gt.txt", "est.txt", "--json", cwd=tmp_path)
    assert p.returncode == 0, p.stderr
    doc = json.loads(p.stdout)
    assert doc["offset"]["applied_s"] == -100 and doc["n_samples"] == 300


@pytest.mark.parametrize(
    ("text", "needle"),
    [
        ("[compare]\nsynk = 'nearest'\n", "[compare] unknown key 'synk'"),
        ("[compare]\nmax_diff = 'big'\n", "[compare] max_diff must be a number"),
        ("colour = 1\n", "unknown key(s) ['colour']"),
        ("[[pair]]\nreference = '/a'\n", "pair #1: 'other' (a topic name) is required"),
        (
            "[[pair]]\nreference='/a'\nother='/b'\n[[pair]]\nreference='/a'\nother='/b'\n",
            "used twice",
        ),
        ("[compare\n", "not valid TOML"),
    ],
)
def test_bad_project_files_are_one_line_errors(tmp_path: Path, text: str, needle: str) -> None:
    (tmp_path / "uwval.toml").write_text(text)
    with pytest.raises(ConfigError, match=None) as exc:
        load_config(cwd=tmp_path)
    assert needle in str(exc.value) and "uwval.toml" in str(exc.value)


def test_a_bad_project_file_on_the_command_line(tmp_path: Path) -> None:
    (tmp_path / "uwval.toml").write_text("[compare]\nsynk = 1\n")
    write_tum(tmp_path / "gt.txt", _pose(1))
    p = run_uwval("compare", "gt.txt", "gt.txt", cwd=tmp_path)
    assert p.returncode == 2
    assert "uwval.toml: [compare] unknown key 'synk'" in p.stderr and "Traceback" not in p.stderr
