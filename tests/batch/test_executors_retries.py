"""Executors do not retry what fails for certain (a deterministic error runs once).

(Named to sort after tests/test_compare_tum.py: a Dask cluster in this process leaves threads
behind, which makes the TUM pair reader choose its sequential path.)"""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

HAS_DASK = importlib.util.find_spec("distributed") is not None


@pytest.mark.skipif(not HAS_DASK, reason="dask.distributed not installed")
def test_dask_does_not_retry_deterministic_errors(tmp_path: Path) -> None:
    import cloudpickle
    import executor_tasks

    from uwval.batch.executors import run_tasks

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
