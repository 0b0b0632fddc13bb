"""Batch compare inputs: finding a sweep's logs, and executors that do not retry what fails
for certain."""

from __future__ import annotations

import importlib.util
import shutil
from pathlib import Path

import pytest
from cli_runner import run_uwval as _uwval

from uwval.batch import items_from

HAS_DASK = importlib.util.find_spec("distributed") is not None


@pytest.fixture(scope="module")
def run_log(tmp_path_factory: pytest.TempPathFactory) -> Path:
    log = tmp_path_factory.mktemp("batch") / "run.mcap"
    res = _uwval("simulate", "--duration", "2", "-o", str(log))
    assert res.returncode == 0, res.stderr
    return log


def test_batch_finds_logs_in_folders_named_like_levels(tmp_path: Path, run_log: Path) -> None:
    for sub in ("force_1.5", "force_2"):
        (tmp_path / sub).mkdir()
        shutil.copy(run_log, tmp_path / sub / f"{sub}.mcap")
    names = sorted(i.name for i in items_from(tmp_path))
    assert names == ["force_1.5", "force_2"]


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
