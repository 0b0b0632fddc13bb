"""Shared benchmark helpers: alternating repetitions, medians, peak memory, one result row.

Every benchmark module ``benchmarks/bench_<area>.py`` exposes
``run(quick: bool = False) -> list[BenchRow]``; ``python -m benchmarks`` runs them all and
prints one table. Benchmarks report targets; tests never assert them.
"""

from __future__ import annotations

import gc
import os
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


#: A minimal launcher (python -S): wait4's ru_maxrss of a child is inherited across exec
#: from the process that forked it, so measuring from this (large) process would report our
#: own peak. The launcher is small; it posix_spawns the command and reports its wall time,
#: peak RSS (MiB) and exit code.
_LAUNCHER = (
    "import os, sys, time\n"
    "t0 = time.perf_counter()\n"
    "pid = os.posix_spawn(sys.argv[1], sys.argv[1:], dict(os.environ),"
    " file_actions=[(os.POSIX_SPAWN_OPEN, 1, os.devnull, os.O_WRONLY, 0)])\n"
    "_, status, ru = os.wait4(pid, 0)\n"
    "print(time.perf_counter() - t0, ru.ru_maxrss / 1024.0, os.waitstatus_to_exitcode(status))\n"
)


def user_env(env: dict[str, str] | None = None) -> dict[str, str]:
    """The environment a user's shell gives a command: ``env`` (default: this one) without
    PYTHONDONTWRITEBYTECODE. A sandbox that sets it makes every run of an editable install
    recompile its sources (~50 ms a command, for the tool under test only: evo's installed
    files were compiled by pip), which users' machines never do."""
    out = dict(os.environ if env is None else env)
    out.pop("PYTHONDONTWRITEBYTECODE", None)
    return out


def run_command(cmd: Sequence[str], env: dict[str, str] | None = None) -> tuple[float, float]:
    """Run a command; return (wall seconds, peak RSS MiB of that command alone)."""
    import shutil

    exe = cmd[0] if "/" in cmd[0] else (shutil.which(cmd[0]) or cmd[0])
    out = subprocess.run(
        [sys.executable, "-S", "-c", _LAUNCHER, exe, *cmd[1:]],
        capture_output=True,
        text=True,
        env=user_env(env),
    )
    if out.returncode != 0 or not out.stdout.strip():
        raise RuntimeError(f"launcher for {' '.join(cmd)} failed: {out.stderr[-2000:]}")
    wall, rss, code = out.stdout.split()
    if int(code) != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed with exit code {code}: {out.stderr[-2000:]}")
    return float(wall), float(rss)


def peak_rss_mib() -> float:
    """Peak RSS of this process so far, MiB."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def python_cmd(*args: str) -> list[str]:
    """A command line running this interpreter."""
    return [sys.executable, *args]
