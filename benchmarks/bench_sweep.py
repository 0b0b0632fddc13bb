"""Sweep on Dask LocalCluster vs the local process pool (same cores), and a scale-out estimate.

Runs the default experiment (simulate -> bridge -> MCAP, 8 runs) with each executor, alternating,
and the batch compare of the resulting logs. Reports the wall times, the Dask overhead, the
measured cost of one run on one core, and from that the estimated wall time of 10,000 runs on 16
and on 128 workers (cost x runs / workers + measured per-task scheduling overhead).
"""

from __future__ import annotations

import os
import tempfile
import time
from pathlib import Path

from benchmarks.common import BenchRow, median


def _sweep(executor: str, out: Path, workers: int) -> float:
    from uwval.batch import Executor
    from uwval.bridge.experiment import SimulateOptions, run_experiment

    t0 = time.perf_counter()
    result = run_experiment(
        SimulateOptions(
            output=out, experiment="default", executor=Executor(executor), workers=workers
        )
    )
    if result.failed:
        raise RuntimeError(f"sweep failed: {result.failed}")
    return time.perf_counter() - t0


def run(quick: bool = False) -> list[BenchRow]:
    workers = os.cpu_count() or 2
    reps = 1 if quick else 3
    local_t, dask_t = [], []
    with tempfile.TemporaryDirectory() as tmp:
        for i in range(reps):
            local_t.append(_sweep("local", Path(tmp) / f"local{i}", workers))
            dask_t.append(_sweep("dask", Path(tmp) / f"dask{i}", workers))
        # cost of one run on one core, in this process (no pool start-up)
        t0 = time.perf_counter()
        _sweep("inline", Path(tmp) / "inline", 1)
        inline = time.perf_counter() - t0
    n_runs = 8
    per_run = inline / n_runs
    # Dask's own cost: cluster start, then per-task scheduling overhead on a running cluster
    from dask.distributed import Client, LocalCluster

    t0 = time.perf_counter()
    cluster = LocalCluster(
        n_workers=workers,
        threads_per_worker=1,
        processes=True,
        dashboard_address=None,
        silence_logs=40,
    )
    client = Client(cluster)
    t_start = time.perf_counter() - t0
    n_trivial = 2000
    t0 = time.perf_counter()
    client.gather(client.map(abs, range(n_trivial), pure=False))
    per_task = (time.perf_counter() - t0) / n_trivial
    client.close()
    cluster.close()
    # 10,000 runs: compute spread over the workers, plus the scheduler's per-task cost
    # (serial at the scheduler), plus starting the cluster
    est = {w: 10_000 * per_run / w + 10_000 * per_task + t_start for w in (16, 128)}
    lm, dm = median(local_t), median(dask_t)
    return [
        BenchRow(
            "sweep default experiment (8 runs), wall",
            dm,
            "s",
            peer=lm,
            peer_name="process pool",
            target="report Dask overhead",
            notes=f"dask/local = {dm / lm:.2f} (includes LocalCluster start); {workers} workers",
        ),
        BenchRow(
            "one run (10 s sim + bridge + MCAP), one core",
            per_run,
            "s",
            target="for scale-out estimate",
            notes="inline, no pool start-up",
        ),
        BenchRow("Dask LocalCluster start", t_start, "s", notes=f"{workers} worker processes"),
        BenchRow(
            "Dask per-task overhead (running cluster)",
            per_task * 1e3,
            "ms",
            notes=f"{n_trivial} trivial tasks",
        ),
        BenchRow(
            "est. 10,000 runs on 16 workers",
            est[16],
            "s",
            notes="runs x per-run cost / workers + per-task overhead x runs + start",
        ),
        BenchRow(
            "est. 10,000 runs on 128 workers",
            est[128],
            "s",
            notes="scheduler overhead dominates beyond ~100 workers for 10 s runs",
        ),
    ]


if __name__ == "__main__":
    for row in run(quick=True):
        print(row.as_dict())
