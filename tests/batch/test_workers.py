"""uwval.workers: calls run on worker threads, results and errors in order, cancellation
(that the compare path no longer imports concurrent.futures: test_compare_imports)."""

from __future__ import annotations

import threading
import time

import pytest

from uwval.workers import CancelledJobError, Workers


def test_results_come_back_per_job_from_named_worker_threads() -> None:
    seen: list[str] = []

    def work(k: int) -> int:
        seen.append(threading.current_thread().name)
        return k * k

    with Workers(2, "uwval-test") as pool:
        jobs = [pool.submit(work, k) for k in range(50)]
        assert [j.result() for j in jobs] == [k * k for k in range(50)]
    assert set(seen) <= {"uwval-test-0", "uwval-test-1"} and seen
    assert all(j.done() for j in jobs)


def test_an_error_is_raised_by_result_with_its_type_and_the_rest_still_run() -> None:
    def work(k: int) -> int:
        if k == 3:
            raise KeyError(k)
        return k

    pool = Workers(1, "uwval-test")
    jobs = [pool.submit(work, k) for k in range(6)]
    with pytest.raises(KeyError):
        jobs[3].result()
    assert [jobs[k].result() for k in (0, 1, 2, 4, 5)] == [0, 1, 2, 4, 5]
    pool.shutdown(cancel=False)


def test_shutdown_with_cancel_drops_calls_not_started_and_joins_the_threads() -> None:
    started = threading.Event()
    release = threading.Event()
    ran: list[int] = []

    def slow(k: int) -> int:
        started.set()
        release.wait(5)
        ran.append(k)
        return k

    pool = Workers(1, "uwval-test")
    jobs = [pool.submit(slow, k) for k in range(4)]
    assert started.wait(5)
    threading.Timer(0.05, release.set).start()
    pool.shutdown(cancel=True)  # returns once the running call ends
    assert ran == [0] and jobs[0].result() == 0
    for j in jobs[1:]:
        assert j.done()
        with pytest.raises(CancelledJobError):
            j.result()
    assert not [t for t in threading.enumerate() if t.name.startswith("uwval-test")]
    with pytest.raises(RuntimeError, match="shut down"):
        pool.submit(slow, 9)


def test_leaving_the_with_block_on_an_error_cancels_what_has_not_started() -> None:
    ran: list[int] = []

    def work(k: int) -> None:
        time.sleep(0.01)
        ran.append(k)

    def submit_then_fail() -> None:
        with Workers(1, "uwval-test") as pool:
            for k in range(20):
                pool.submit(work, k)
            raise ZeroDivisionError

    with pytest.raises(ZeroDivisionError):
        submit_then_fail()
    assert len(ran) < 20


def test_a_pool_needs_a_thread() -> None:
    with pytest.raises(ValueError, match="at least one"):
        Workers(0, "uwval-test")
