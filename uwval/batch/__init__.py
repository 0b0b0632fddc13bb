"""Scale-out: many runs or many logs at once, on a process pool or Dask (docs/scale-out.md).

* :mod:`uwval.batch.executors`: ``run_tasks`` runs independent tasks locally (process pool),
  inline or on ``dask.distributed``, with retries of transient failures;
* :mod:`uwval.batch.inputs`: the logs of a manifest or a directory (remote URLs only when
  the user allowed their protocol);
* :mod:`uwval.batch.compare`: ``compare_batch`` compares every log into one results table.
"""

from uwval.batch.compare import BatchResult, compare_batch, compare_item
from uwval.batch.executors import EXECUTORS, Executor, TaskOutcome, run_tasks
from uwval.batch.inputs import (
    ALLOW_PROTOCOLS_ENV,
    LOG_SUFFIXES,
    BatchItem,
    allowed_protocols,
    check_remote_allowed,
    is_url,
    items_from,
    url_protocols,
)

__all__ = [
    "ALLOW_PROTOCOLS_ENV",
    "EXECUTORS",
    "LOG_SUFFIXES",
    "BatchItem",
    "BatchResult",
    "Executor",
    "TaskOutcome",
    "allowed_protocols",
    "check_remote_allowed",
    "compare_batch",
    "compare_item",
    "is_url",
    "items_from",
    "run_tasks",
    "url_protocols",
]
