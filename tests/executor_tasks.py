"""Module-level task functions for the executor tests (pickled to worker processes)."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from uwval.errors import ConfigError


def seeded_sum(seed: int) -> float:
    """A deterministic numeric task: same seed, same number on any worker."""
    return float(np.random.default_rng(seed).normal(size=1000).sum())


def fail_on_three(x: int) -> int:
    """Fails deterministically (a uwval error) for x == 3."""
    if x == 3:
        raise ConfigError(f"run {x}: bad parameter 'xDotU'")
    return x * x


def die_once(args: tuple[int, str]) -> int:
    """Kills its worker process the first time it sees x == 2 (marker file), then succeeds."""
    x, marker_dir = args
    marker = Path(marker_dir) / f"died-{x}"
    if x == 2 and not marker.exists():
        marker.write_text("x")
        os._exit(17)
    return x + 100


def flaky_once(args: tuple[int, str]) -> int:
    """Raises a transient OSError the first time for each x, then succeeds."""
    x, marker_dir = args
    marker = Path(marker_dir) / f"flaky-{x}"
    if not marker.exists():
        marker.write_text("x")
        raise OSError(f"transient failure for {x}")
    return x


def run_one_dying_once(args: tuple[object, str, str]) -> dict[str, object]:
    """A real sweep task (simulate -> bridge -> log) whose worker process is killed the first
    time it runs the run named ``victim``."""
    from uwval.bridge.experiment import RunJob, run_one

    job, victim, marker_dir = args
    assert isinstance(job, RunJob)
    marker = Path(marker_dir) / "killed"
    if job.spec.name == victim and not marker.exists():
        marker.write_text(victim)
        os._exit(9)
    return run_one(job)


def count_and_fail(args: tuple[int, str]) -> int:
    """Records each attempt in a file, then fails deterministically (a uwval error)."""
    x, marker_dir = args
    with open(Path(marker_dir) / f"attempts-{x}", "a") as fh:
        fh.write("x")
    raise ConfigError(f"run {x}: bad parameter")


def spin_forever(args: tuple[int, str]) -> int:
    """Writes its worker's pid into ``pid_dir`` then burns CPU for up to 10 minutes (a run
    that would outlive a test by far if nobody stopped it)."""
    x, pid_dir = args
    (Path(pid_dir) / f"{os.getpid()}.pid").write_text(str(os.getpid()))
    import time

    end = time.monotonic() + 600
    while time.monotonic() < end:
        pass
    return x
