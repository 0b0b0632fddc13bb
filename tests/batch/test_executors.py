"""Executors: local process pool, inline and Dask distributed give the same outcomes."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import executor_tasks as tasks
import pytest

from uwval.batch.executors import run_tasks

HAS_DASK = importlib.util.find_spec("distributed") is not None


@pytest.mark.parametrize("executor", ["inline", "local"])
def test_results_in_order_and_failures_named(executor: str) -> None:
    out = run_tasks(
        tasks.fail_on_three,
        list(range(6)),
        [f"run{i}" for i in range(6)],
        executor=executor,
        workers=2,
        progress=False,
    )
    assert [o.key for o in out] == [f"run{i}" for i in range(6)]
    assert [o.value for o in out if o.ok] == [0, 1, 4, 16, 25]
    bad = [o for o in out if not o.ok]
    assert len(bad) == 1 and bad[0].key == "run3"
    assert "xDotU" in bad[0].error
    assert bad[0].attempts == 1  # a deterministic uwval error is not retried


def test_transient_failure_retried(tmp_path: Path) -> None:
    items = [(i, str(tmp_path)) for i in range(3)]
    out = run_tasks(
        tasks.flaky_once, items, ["a", "b", "c"], executor="inline", retries=1, progress=False
    )
    assert all(o.ok for o in out)
    assert [o.attempts for o in out] == [2, 2, 2]
    (tmp_path / "x").mkdir()
    out = run_tasks(
        tasks.flaky_once,
        [(9, str(tmp_path / "x"))],
        ["z"],
        executor="inline",
        retries=0,
        progress=False,
    )
    assert not out[0].ok and "transient failure for 9" in out[0].error


def test_killed_local_worker_sweep_completes(tmp_path: Path) -> None:
    items = [(i, str(tmp_path)) for i in range(5)]
    out = run_tasks(
        tasks.die_once,
        items,
        [f"r{i}" for i in range(5)],
        executor="local",
        workers=2,
        retries=2,
        progress=False,
    )
    assert [o.value for o in out] == [100, 101, 102, 103, 104]
    assert (tmp_path / "died-2").exists()


@pytest.mark.skipif(not HAS_DASK, reason="dask.distributed not installed")
def test_dask_local_cluster_identical_to_local(tmp_path: Path) -> None:
    import cloudpickle

    cloudpickle.register_pickle_by_value(tasks)
    seeds = list(range(8))
    keys = [f"seed{s}" for s in seeds]
    local = run_tasks(tasks.seeded_sum, seeds, keys, executor="local", workers=2, progress=False)
    dask = run_tasks(tasks.seeded_sum, seeds, keys, executor="dask", workers=2, progress=False)
    assert [o.value for o in dask] == [o.value for o in local]
    # a worker killed mid-sweep: the task is rescheduled and every run is present once
    items = [(i, str(tmp_path)) for i in range(5)]
    out = run_tasks(
        tasks.die_once,
        items,
        [f"r{i}" for i in range(5)],
        executor="dask",
        workers=2,
        retries=2,
        progress=False,
    )
    assert [o.key for o in out] == [f"r{i}" for i in range(5)]
    assert [o.value for o in out] == [100, 101, 102, 103, 104]
