"""Issue 33 point 5 / issue 30 point 1, end to end: output for scripts (no wrapping when piped,
tables on stdout, errors on stderr), one name and one kind per option across compare, rpe,
doctor and inspect, ``uwval --version`` naming the embedded defaults, and one parser."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from cli_runner import run_uwval

from uwval.comparison.synthetic import unity_view, vehicle_motion
from uwval.io.tum import write_tum

#: a folder name that makes every printed path wider than 80 columns
LONG = "a_folder_name_long_enough_that_no_line_naming_it_fits_in_eighty_columns_of_a_terminal"


@pytest.fixture
def pair(tmp_path: Path) -> tuple[Path, Path]:
    """Two TUM files (Unity view of a seeded motion) under a long folder name."""
    folder = tmp_path / LONG
    folder.mkdir()
    g = vehicle_motion(300, 50.0, seed=11)
    write_tum(folder / "gt.tum", g)
    write_tum(folder / "est.tum", unity_view(g, convention="enu", rate_hz=50.0, seed=12))
    return folder / "gt.tum", folder / "est.tum"


def test_piped_tables_are_not_wrapped(pair: tuple[Path, Path]) -> None:
    p = run_uwval("compare", *pair)
    assert p.returncode == 0, p.stderr
    title = next(ln for ln in p.stdout.splitlines() if ln.startswith("trajectory:"))
    assert str(pair[1]) in title and str(pair[0]) in title  # one line, however long
    assert max(len(ln) for ln in p.stdout.splitlines()) > 120
    header = next(ln for ln in p.stdout.splitlines() if ln.lstrip().startswith("axis"))
    assert "Pearson 95% CI" in header and header.rstrip().endswith("n")  # every column
    assert p.stderr == ""


def test_errors_on_stderr_one_line_not_wrapped(pair: tuple[Path, Path]) -> None:
    missing = pair[0].parent / "missing_file_with_a_long_name_as_well.tum"
    p = run_uwval("compare", pair[0], missing)
    assert p.returncode == 2
    assert p.stdout == ""
    assert p.stderr.count("\n") == 1 and str(missing) in p.stderr


def test_doctor_and_inspect_pipe_unwrapped_and_o_is_the_json(
    pair: tuple[Path, Path], tmp_path: Path
) -> None:
    out = tmp_path / "doctor.json"
    p = run_uwval("doctor", *pair, "-o", out)
    assert p.returncode == 0, p.stderr
    assert json.loads(out.read_text())["trajectory"]["configured"] == "enu"
    q = run_uwval("inspect", pair[0], "-o", tmp_path / "inspect.json")
    assert q.returncode == 0, q.stderr
    assert str(pair[0]) in q.stdout.splitlines()[0]  # the title: one line
    assert json.loads((tmp_path / "inspect.json").read_text())["path"] == str(pair[0])


def test_o_is_the_json_result_in_compare_and_rpe(pair: tuple[Path, Path], tmp_path: Path) -> None:
    for command in ("compare", "rpe"):
        out = tmp_path / f"{command}.json"
        p = run_uwval(command, *pair, "-o", out)
        assert p.returncode == 0, p.stderr
        assert json.loads(out.read_text())["sources"] == [str(pair[0]), str(pair[1])]
    for command in ("compare", "rpe", "doctor", "inspect"):
        boxed = run_uwval(command, "--help").stdout.replace("\u2502", " ")  # rich's box sides
        help_text = " ".join(boxed.split())
        assert "Write the JSON result to this file" in help_text, command


@pytest.mark.parametrize("command", ["compare", "rpe"])
def test_one_name_and_kind_per_option(pair: tuple[Path, Path], command: str) -> None:
    """--t-max-diff and --align MODE (with evo's -a / bare --align) mean the same in both."""
    docs = []
    for args in (["--align", "se3"], ["-a"], ["--align"]):
        p = run_uwval(command, *pair, "--t-max-diff", "0.02", *args, "--json")
        assert p.returncode == 0, (args, p.stderr)
        docs.append(json.loads(p.stdout))
    assert all(d["alignment"]["mode"] == "se3" for d in docs)
    assert docs[0] == docs[1] == docs[2]
    assert all(d["sync"]["max_diff_s"] == 0.02 for d in docs)


def test_version_names_the_embedded_defaults() -> None:
    p = run_uwval("--version")
    assert p.returncode == 0, p.stderr
    lines = p.stdout.splitlines()
    assert lines[0].startswith("uwval ")
    assert "embedded experiments: bluerov2_sweep, default, quick" in lines
    assert "embedded thresholds: default" in lines
    assert "embedded baselines: default" in lines


def test_one_parser_no_fast_path() -> None:
    import uwval.cli

    assert not hasattr(uwval.cli, "_exit_now")
    with pytest.raises(ModuleNotFoundError):
        __import__("uwval.cli.compare_run")


def test_batch_o_is_deprecated_for_results_dir(tmp_path: Path) -> None:
    p = run_uwval("compare", tmp_path / "nothing.mcap", "--results-dir", tmp_path / "r")
    assert p.returncode == 2 and "--results-dir applies to --batch only" in p.stderr


def test_an_existing_file_named_like_evos_word_is_a_file(
    pair: tuple[Path, Path], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    shutil.copyfile(pair[0], tmp_path / "tum")
    monkeypatch.chdir(tmp_path)
    p = run_uwval("compare", "tum", pair[1], "--format", "tum", "--json", cwd=tmp_path)
    assert p.returncode == 0, p.stderr
    assert json.loads(p.stdout)["sources"][0] == "tum"


def test_the_html_page_says_how_the_numbers_were_made(
    pair: tuple[Path, Path], tmp_path: Path
) -> None:
    page = tmp_path / "c.html"
    p = run_uwval("compare", *pair, "--html", page, "-a")
    assert p.returncode == 0, p.stderr
    assert "sync nearest (max diff 0.01 s), align se3, frame enu" in page.read_text()


def test_piped_help_is_not_wrapped_at_80_columns() -> None:
    """``uwval compare --help | grep`` finds an option with its whole help on one line (as a
    shell runs it: COLUMNS is a shell variable, not exported; pytest exports COLUMNS=80)."""
    env = {k: v for k, v in os.environ.items() if k != "COLUMNS"}
    res = subprocess.run(
        [sys.executable, "-m", "uwval", "compare", "--help"],
        capture_output=True,
        text=True,
        env=env,
        stdin=subprocess.DEVNULL,
        timeout=120,
    )
    assert res.returncode == 0
    line = next(ln for ln in res.stdout.splitlines() if "--gazebo-topic" in ln)
    assert "chained through /tf_static" in line
