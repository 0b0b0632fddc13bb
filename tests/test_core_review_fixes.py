"""Regressions found in review of the core and the CLI: every one a clean error or a result
that is no longer silently wrong."""

from __future__ import annotations

import importlib.util
import json
import shutil
from pathlib import Path

import pytest
from cli_runner import run_uwval as _uwval

from uwval.batch import items_from
from uwval.cli.pipeline import SessionOptions
from uwval.cli.simulate_cmd import run_experiment
from uwval.resources import data_path

HAS_DASK = importlib.util.find_spec("distributed") is not None


@pytest.fixture(scope="module")
def run_log(tmp_path_factory: pytest.TempPathFactory) -> Path:
    log = tmp_path_factory.mktemp("rv") / "run.mcap"
    res = _uwval(
        "simulate", "--force", "10,0,0", "--torque", "0,0,1", "--duration", "5", "-o", str(log)
    )
    assert res.returncode == 0, res.stderr
    return log


def test_batch_finds_logs_in_folders_named_like_levels(tmp_path: Path, run_log: Path) -> None:
    for sub in ("force_1.5", "force_2"):
        (tmp_path / sub).mkdir()
        shutil.copy(run_log, tmp_path / sub / f"{sub}.mcap")
    names = sorted(i.name for i in items_from(tmp_path))
    assert names == ["force_1.5", "force_2"]


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        (["--offset", "nan"], "finite"),
        (["--offset", "inf"], "finite"),
        (["--max-gap", "-1"], "max_gap"),
        (["--max-gap", "0"], "max_gap"),
        (["--sync", "nearest", "--max-diff", "-1"], "max_diff"),
        (["--format", "foo"], "--format 'foo'"),
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


def test_check_on_a_manifest_with_one_bad_log_checks_the_rest(tmp_path: Path) -> None:
    m = run_experiment(
        data_path("experiments", "default.toml"),
        tmp_path / "exp",
        SessionOptions(),
        executor="inline",
        progress=False,
    )
    bad = m["runs"][2]
    (tmp_path / "exp" / bad["log"]).write_bytes(b"garbage")
    res = _uwval(
        "check", str(tmp_path / "exp"), "--thresholds", str(data_path("thresholds", "default.toml"))
    )
    assert res.returncode == 1, res.stdout + res.stderr
    assert "1 run(s) failed" in res.stderr
    assert bad["name"] in res.stderr
    assert "values checked" in res.stdout + res.stderr  # the other runs were gated


def test_csv_accepts_the_same_frame_aliases(tmp_path: Path) -> None:
    from uwval.io import read_stream

    csv = tmp_path / "u.csv"
    csv.write_text("time,x,y,z,qx,qy,qz,qw\n0.0,1,2,3,0,0,0,1\n0.1,1,2,3,0,0,0,1\n")
    assert read_stream(csv, "", frame="unity").frame == "unity-flu"


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


@pytest.mark.skipif(not HAS_DASK, reason="dask.distributed not installed")
def test_dask_does_not_retry_deterministic_errors(tmp_path: Path) -> None:
    import cloudpickle
    import executor_tasks

    from uwval.executors import run_tasks

    cloudpickle.register_pickle_by_value(executor_tasks)
    out = run_tasks(
        executor_tasks.count_and_fail,
        [(1, str(tmp_path))],
        ["one"],
        executor="dask",
        workers=1,
        retries=3,
        progress=False,
    )
    assert not out[0].ok
    assert "bad parameter" in out[0].error
    assert (tmp_path / "attempts-1").read_text() == "x"  # ran once, not 1 + 3 times
