"""Whether a second thread can gain: the CPUs this process may use, and how busy they are."""

from __future__ import annotations

import os


def second_cpu_free() -> bool:
    """Whether this process may run on two CPUs and the last minute's load (which counts
    this process) leaves one of them free on average: a second thread gains only on a CPU
    that is not busy (on a busy one, switching between the threads cost ~15 % more than
    doing the work on one: measured comparing a log's two pose pairs)."""
    try:
        cpus = len(os.sched_getaffinity(0))
    except (AttributeError, OSError):  # not Linux
        cpus = os.cpu_count() or 1
    try:
        load = os.getloadavg()[0]
    except (AttributeError, OSError):  # no load average (Windows)
        load = 0.0
    return cpus >= 2 and load < cpus - 0.5
