"""A few worker threads taking calls in order: what the read and compare paths need of
``concurrent.futures.ThreadPoolExecutor``, without importing it.

``concurrent.futures`` loads :mod:`logging` and its own machinery (~3.5 ms, measured with
``python -X importtime``), paid by every ``uwval compare`` whose whole run is ~0.2 s. These
paths only submit calls, wait for their results in order, and cancel what has not started
when they stop early (an error, Ctrl-C): that is all this module does.
"""

from __future__ import annotations

import threading
from _queue import Empty, SimpleQueue  # queue.SimpleQueue's C queue, without queue's import
from collections.abc import Callable
from typing import Any, Generic, TypeVar

T = TypeVar("T")


class CancelledJobError(RuntimeError):
    """The job was cancelled (its pool shut down) before a worker started it."""


class Job(Generic[T]):
    """One submitted call: :meth:`result` waits for it, then returns its value or raises its
    exception (with the worker's traceback)."""

    __slots__ = ("_args", "_done", "_error", "_fn", "_value")

    def __init__(self, fn: Callable[..., T], args: tuple[Any, ...]) -> None:
        self._fn: Callable[..., T] | None = fn
        self._args = args
        self._done = threading.Event()
        self._value: T | None = None
        self._error: BaseException | None = None

    def _run(self) -> None:
        fn, args = self._fn, self._args
        self._fn, self._args = None, ()  # the call's inputs are let go once it has run
        try:
            if fn is None:
                raise CancelledJobError("the job was cancelled before it started")
            self._value = fn(*args)
        except BaseException as exc:  # handed to the waiting thread by result()
            self._error = exc
        finally:
            self._done.set()

    def _cancel(self) -> None:
        self._fn = None

    def done(self) -> bool:
        """Whether the call has finished (or was cancelled)."""
        return self._done.is_set()

    def result(self) -> T:
        """The call's value, once it has run; its exception is raised here."""
        self._done.wait()
        if self._error is not None:
            raise self._error
        return self._value  # type: ignore[return-value]


class Workers:
    """``n`` daemon threads named ``name``-k running submitted calls in submission order
    (each thread takes the next waiting call). Threads start with the first submit."""

    def __init__(self, n: int, name: str) -> None:
        if n < 1:
            raise ValueError(f"a pool needs at least one worker thread, not {n}")
        self.n, self.name = n, name
        self._queue: SimpleQueue[Job[Any] | None] = SimpleQueue()
        self._threads: list[threading.Thread] = []
        self._closed = False

    def submit(self, fn: Callable[..., T], *args: Any) -> Job[T]:
        """Run ``fn(*args)`` on a worker thread; the returned job holds its outcome."""
        if self._closed:
            raise RuntimeError(f"worker pool {self.name!r} is shut down")
        job: Job[T] = Job(fn, args)
        self._queue.put(job)
        if len(self._threads) < self.n:
            t = threading.Thread(
                target=self._work, name=f"{self.name}-{len(self._threads)}", daemon=True
            )
            t.start()
            self._threads.append(t)
        return job

    def _work(self) -> None:
        while True:
            job = self._queue.get()
            if job is None:
                return
            job._run()

    def shutdown(self, *, cancel: bool = True) -> None:
        """Stop the threads once their current calls end and wait for them; with ``cancel``,
        calls not started yet are not run (their :meth:`Job.result` raises
        :class:`CancelledJobError`)."""
        self._closed = True
        if cancel:  # the calls still queued end cancelled here (a running one is not stopped)
            while True:
                try:
                    job = self._queue.get_nowait()
                except Empty:
                    break
                if job is not None:
                    job._cancel()
                    job._run()
        for _ in self._threads:
            self._queue.put(None)
        for t in self._threads:
            t.join()

    def __enter__(self) -> Workers:
        return self

    def __exit__(self, *exc: object) -> None:
        self.shutdown(cancel=exc[0] is not None)
