"""Shared benchmark helpers: alternating repetitions, medians, peak memory, one result row.

Every benchmark module ``benchmarks/bench_<area>.py`` exposes
``run(quick: bool = False) -> list[BenchRow]``; ``python -m benchmarks`` runs them all and
prints one table. Benchmarks report targets; tests never assert them.
"""

from __future__ import annotations

import gc
import resource
import statistics
import subprocess
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from typing import Any


@dataclass
class BenchRow:
    """One measured comparison: uwval vs a peer (or vs a target when there is no peer)."""

    name: str
    uwval: float  # median of the measured quantity for uwval
    unit: str  # "s", "msg/s", "RTF", "MiB", ...
    peer: float | None = None  # the peer's median, same unit
    peer_name: str = ""
    target: str = ""  # e.g. ">= 10x faster", ">= 1.2M msg/s"
    met: bool | None = None
    notes: str = ""
    extra: dict[str, Any] = field(default_factory=dict)

    @property
    def ratio(self) -> float | None:
        """Peer / uwval for times (bigger = uwval faster); uwval / peer for rates."""
        if self.peer is None or self.peer == 0 or self.uwval == 0:
            return None
        if self.unit in ("s", "ms", "MiB"):
            return self.peer / self.uwval
        return self.uwval / self.peer

    def as_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["ratio"] = self.ratio
        return d


def alternate(fns: Sequence[Callable[[], Any]], reps: int = 5) -> list[list[float]]:
    """Time each callable ``reps`` times, alternating A, B, A, B... Returns seconds per fn."""
    times: list[list[float]] = [[] for _ in fns]
    for _ in range(reps):
        for i, fn in enumerate(fns):
            gc.collect()
            t0 = time.perf_counter()
            fn()
            times[i].append(time.perf_counter() - t0)
    return times


def median(xs: Sequence[float]) -> float:
    return float(statistics.median(xs))


def run_command(cmd: Sequence[str], env: dict[str, str] | None = None) -> tuple[float, float]:
    """Run a command; return (wall seconds, peak RSS MiB of the child) via /usr/bin/time-free
    accounting: wait4's ru_maxrss of that child alone."""
    t0 = time.perf_counter()
    proc = subprocess.Popen(list(cmd), stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, env=env)
    _, status, ru = _wait4(proc.pid)
    wall = time.perf_counter() - t0
    if status != 0:
        err = proc.stderr.read().decode(errors="replace") if proc.stderr else ""
        raise RuntimeError(f"{' '.join(cmd)} failed ({status}): {err[-2000:]}")
    return wall, ru.ru_maxrss / 1024.0


def _wait4(pid: int) -> tuple[int, int, Any]:
    import os

    p, status, ru = os.wait4(pid, 0)
    return p, os.waitstatus_to_exitcode(status), ru


def peak_rss_mib() -> float:
    """Peak RSS of this process so far, MiB."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def python_cmd(*args: str) -> list[str]:
    """A command line running this interpreter."""
    return [sys.executable, *args]
