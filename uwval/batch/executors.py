"""Run many independent tasks (one run, or one log, each) locally or on Dask distributed.

``run_tasks`` is the one entry point: the local executor is a process pool (default); the
``dask`` executor submits the same function to a ``dask.distributed`` cluster (an existing
scheduler by address, or a LocalCluster it starts). Dask is imported only when asked for.
A failing task is reported with its key and cause while the others complete; failures that
are not uwval's own deterministic errors (a worker killed, a broken pool, an OS error) are
retried a bounded number of times.

Stopping: SIGTERM or SIGINT (Ctrl-C) to the process running ``run_tasks`` stops its worker
processes too (they are terminated, then killed, before the exception goes on: SIGTERM ends
the process with status 143); and a worker whose parent died anyway (SIGKILL) notices it
within half a second and exits, so no worker is left computing for nobody.
"""

from __future__ import annotations

import os
import signal
import threading
import time
import traceback
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from contextlib import contextmanager
from dataclasses import dataclass
from multiprocessing import get_context
from typing import Any, Generic, TypeVar

from uwval.compat import StrEnum
from uwval.errors import UwvalError

T = TypeVar("T")
R = TypeVar("R")


class Executor(StrEnum):
    """Where tasks run (a StrEnum: each equals its CLI string)."""

    LOCAL = "local"
    DASK = "dask"
    INLINE = "inline"


EXECUTORS = tuple(e.value for e in Executor)

#: Seconds a worker is given to end after SIGTERM before it is killed.
TERMINATE_GRACE_S = 2.0

#: How often (s) a worker checks that the process that started it is still alive.
PARENT_POLL_S = 0.5


@contextmanager
def _sigterm_raises() -> Iterator[None]:
    """While inside, SIGTERM raises ``SystemExit(143)`` in the main thread (so cleanup runs,
    as for Ctrl-C's KeyboardInterrupt); a handler someone else installed is left alone."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.getsignal(signal.SIGTERM)
    if previous not in (signal.SIG_DFL, None):
        yield
        return

    def _raise(signum: int, _frame: Any) -> None:
        raise SystemExit(128 + signum)

    signal.signal(signal.SIGTERM, _raise)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def _watch_parent(parent_pid: int) -> None:
    """Worker initializer: exit when the parent process is gone (e.g. it was SIGKILLed), and
    leave SIGINT to the parent (a Ctrl-C reaches the whole process group at once)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)

    def _poll() -> None:
        while True:
            time.sleep(PARENT_POLL_S)
            if os.getppid() != parent_pid:
                os._exit(1)

    threading.Thread(target=_poll, name="uwval-parent-watch", daemon=True).start()


def _stop_workers(pool: ProcessPoolExecutor) -> None:
    """Terminate the pool's worker processes now (a running task is not waited for), kill
    those still alive after ``TERMINATE_GRACE_S``, and cancel what has not started."""
    procs = list((getattr(pool, "_processes", None) or {}).values())
    for p in procs:
        if p.is_alive():
            p.terminate()
    deadline = time.monotonic() + TERMINATE_GRACE_S
    for p in procs:
        p.join(max(0.0, deadline - time.monotonic()))
        if p.is_alive():
            p.kill()
            p.join(1.0)
    pool.shutdown(wait=False, cancel_futures=True)


@dataclass
class TaskOutcome(Generic[R]):
    """What became of one task: its value, or the cause of its failure."""

    key: str
    ok: bool
    value: R | None = None
    error: str = ""
    attempts: int = 1


def _describe_exc(exc: BaseException) -> str:
    if isinstance(exc, UwvalError):
        return str(exc)
    tb = traceback.format_exception_only(type(exc), exc)
    return "".join(tb).strip()


def _is_transient(exc: BaseException) -> bool:
    """uwval's own errors are deterministic (bad input): retrying cannot help."""
    return not isinstance(exc, UwvalError | ValueError | TypeError | KeyError)


class _Progress:
    """A rich progress bar, or nothing when progress is off."""

    def __init__(self, total: int, description: str, enabled: bool) -> None:
        self._bar: Any = None
        if enabled and total:
            from rich.progress import (
                BarColumn,
                MofNCompleteColumn,
                Progress,
                TextColumn,
                TimeElapsedColumn,
            )

            self._bar = Progress(
                TextColumn("[bold]{task.description}"),
                BarColumn(),
                MofNCompleteColumn(),
                TimeElapsedColumn(),
                transient=False,
            )
            self._bar.start()
            self._task = self._bar.add_task(description, total=total)

    def advance(self) -> None:
        if self._bar is not None:
            self._bar.advance(self._task)

    def close(self) -> None:
        if self._bar is not None:
            self._bar.stop()


def run_tasks(
    fn: Callable[[T], R],
    items: Sequence[T],
    keys: Sequence[str],
    *,
    executor: Executor | str = Executor.LOCAL,
    workers: int | None = None,
    scheduler: str | None = None,
    retries: int = 2,
    progress: bool = True,
    description: str = "tasks",
) -> list[TaskOutcome[R]]:
    """Apply ``fn`` to every item; outcomes come back in the order of ``items``.

    ``fn`` must be a module-level function (it is pickled to worker processes).
    ``executor``: ``local`` (process pool of ``workers``, default all cores), ``dask``
    (``scheduler`` address, or a LocalCluster of ``workers`` processes), or ``inline``
    (this process, for debugging). ``retries`` bounds re-runs of transient failures.
    """
    if len(items) != len(keys):
        raise ValueError("items and keys differ in length")
    if len(set(keys)) != len(keys):
        raise ValueError("task keys must be unique")
    bar = _Progress(len(items), description, progress)
    try:
        with _sigterm_raises():
            return _dispatch(fn, items, keys, executor, workers, scheduler, retries, bar)
    finally:
        bar.close()


def _dispatch(
    fn: Callable[[T], R],
    items: Sequence[T],
    keys: Sequence[str],
    executor: Executor | str,
    workers: int | None,
    scheduler: str | None,
    retries: int,
    bar: _Progress,
) -> list[TaskOutcome[R]]:
    """Run the tasks on the chosen executor (see :func:`run_tasks`)."""
    if executor == "inline":
        return _run_inline(fn, items, keys, retries, bar)
    if executor == "local":
        return _run_local(fn, items, keys, workers, retries, bar)
    if executor == "dask":
        return _run_dask(fn, items, keys, workers, scheduler, retries, bar)
    raise UwvalError(f"unknown executor {executor!r}; choose one of {', '.join(EXECUTORS)}")


def _run_inline(
    fn: Callable[[T], R], items: Sequence[T], keys: Sequence[str], retries: int, bar: _Progress
) -> list[TaskOutcome[R]]:
    out: list[TaskOutcome[R]] = []
    for item, key in zip(items, keys, strict=True):
        attempt = 0
        while True:
            attempt += 1
            try:
                out.append(TaskOutcome(key, True, fn(item), attempts=attempt))
                break
            except Exception as exc:
                if attempt <= retries and _is_transient(exc):
                    continue
                out.append(TaskOutcome(key, False, error=_describe_exc(exc), attempts=attempt))
                break
        bar.advance()
    return out


def _run_local(
    fn: Callable[[T], R],
    items: Sequence[T],
    keys: Sequence[str],
    workers: int | None,
    retries: int,
    bar: _Progress,
) -> list[TaskOutcome[R]]:
    n_workers = max(1, min(workers or os.cpu_count() or 1, len(items) or 1))
    results: dict[int, TaskOutcome[R]] = {}
    attempts = dict.fromkeys(range(len(items)), 0)
    pending = list(range(len(items)))
    while pending:
        # a killed worker breaks the whole pool: start a new one for what is left
        pool = ProcessPoolExecutor(
            n_workers,
            mp_context=get_context("spawn"),
            initializer=_watch_parent,
            initargs=(os.getpid(),),
        )
        try:
            futures: dict[Future[R], int] = {}
            for i in pending:
                attempts[i] += 1
                futures[pool.submit(fn, items[i])] = i
            pending = []
            not_done = set(futures)
            while not_done:
                done, not_done = wait(not_done, return_when=FIRST_COMPLETED)
                for fut in done:
                    i = futures[fut]
                    try:
                        results[i] = TaskOutcome(keys[i], True, fut.result(), attempts=attempts[i])
                        bar.advance()
                    except Exception as exc:
                        broken = isinstance(exc, BrokenProcessPool)
                        if (broken or _is_transient(exc)) and attempts[i] <= retries:
                            pending.append(i)
                        else:
                            results[i] = TaskOutcome(
                                keys[i], False, error=_describe_exc(exc), attempts=attempts[i]
                            )
                            bar.advance()
        except BaseException:
            # SIGTERM (SystemExit), Ctrl-C or an error here: do not wait for running tasks
            _stop_workers(pool)
            raise
        else:
            pool.shutdown(wait=True)
    return [results[i] for i in range(len(items))]


def _guarded(task: tuple[Callable[[Any], Any], Any]) -> tuple[bool, Any]:
    """Run one task on a worker: (True, value), or (False, message) for a deterministic
    error; transient failures are raised so that Dask retries them."""
    fn, item = task
    try:
        return True, fn(item)
    except Exception as exc:
        if _is_transient(exc):
            raise
        return False, _describe_exc(exc)


def _run_dask(
    fn: Callable[[T], R],
    items: Sequence[T],
    keys: Sequence[str],
    workers: int | None,
    scheduler: str | None,
    retries: int,
    bar: _Progress,
) -> list[TaskOutcome[R]]:
    try:
        from dask.distributed import Client, LocalCluster, as_completed
    except ImportError as exc:
        raise UwvalError(
            "the dask executor needs dask.distributed: pip install 'uwval[dask]'"
        ) from exc
    cluster = None
    if scheduler:
        client = Client(scheduler, timeout="30s")
    else:
        cluster = LocalCluster(
            n_workers=workers or os.cpu_count() or 1,
            threads_per_worker=1,
            processes=True,
            dashboard_address=None,
            silence_logs=40,
        )
        client = Client(cluster)
    try:
        # one Dask key per task, named after the run/log so failures are traceable
        # deterministic errors come back as values (Dask would retry any exception)
        futs = [
            client.submit(_guarded, (fn, item), key=f"uwval-{key}", retries=retries, pure=False)
            for item, key in zip(items, keys, strict=True)
        ]
        index = {f.key: i for i, f in enumerate(futs)}
        results: dict[int, TaskOutcome[R]] = {}
        for fut in as_completed(futs):
            i = index[fut.key]
            if i in results:
                continue
            # result() waits for the final state: a task lost with a killed worker is
            # rescheduled by the scheduler, and its future may be seen before that settles
            try:
                ok, value = fut.result()
            except Exception as exc:
                results[i] = TaskOutcome(
                    keys[i], False, error=_describe_exc(exc), attempts=retries + 1
                )
            else:
                results[i] = (
                    TaskOutcome(keys[i], True, value)
                    if ok
                    else TaskOutcome(keys[i], False, error=value)
                )
            bar.advance()
        return [results[i] for i in range(len(items))]
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
