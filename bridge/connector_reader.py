"""ROS-TCP-Connector's reader task, one implementation for the wall clock and the virtual clock.

Unity's ``ROSConnection`` (ROS-TCP-Connector 0.7.0, ``ReaderThread`` and ``ReadToByteArray``)
reads the socket on a background task: while bytes are available it reads message after
message and queues each; when none are (``NetworkStream.DataAvailable`` false) it sleeps
``SleepTimeSeconds`` (10 ms, ``await Task.Delay(10)``) and looks again. ``Update`` then
dequeues everything queued and calls the subscribers, once per render frame. So a message
waits for the reader's next look (0-10 ms after it reached the socket when the reader is idle)
and then for the next frame.

:class:`ConnectorReader` is that loop. It runs against a :class:`ReaderPort`: the live client's
port is a real socket and the wall clock (:class:`uwval.bridge.unity_client.UnityClient` runs it
on a thread); the virtual model's port (:class:`VirtualPort`) holds the arrival times the
transport model gave and a virtual clock whose sleep only advances the clock. Each seed draws
the reader's poll phase (when its first look happens after connecting).
"""

from __future__ import annotations

import math
import time
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Generic, Protocol, TypeVar

import numpy as np

from uwval.bridge.errors import BridgeError

#: ROS-TCP-Connector's ``SleepTimeSeconds`` default: the reader's idle sleep, s.
CONNECTOR_SLEEP_S = 0.010

Item = TypeVar("Item")


class ReaderPort(Protocol):
    """What the reader loop reads from and sleeps on (a real socket or the virtual model)."""

    def now_ns(self) -> int:
        """The port's clock, ns."""
        ...

    def read_available(self, now_ns: int) -> bool:
        """Read every message available at ``now_ns`` and queue each (stamped ``now_ns``);
        False when nothing was available."""
        ...

    def sleep_ns(self, ns: int) -> None:
        """Sleep ``ns`` on the port's clock."""
        ...


@dataclass
class ConnectorReader:
    """The Connector's reader loop: drain while data is available, else sleep ``sleep_s``.

    Args:
        sleep_s: idle sleep between looks at the socket, s (the Connector's 10 ms).
        seed: seeds the poll phase drawn at each (re)connect (:meth:`phase_ns`).
    """

    sleep_s: float = CONNECTOR_SLEEP_S
    seed: int = 0
    _rng: np.random.Generator = field(init=False, repr=False)

    def __post_init__(self) -> None:
        if not (0 < self.sleep_s < math.inf):
            raise BridgeError(f"reader sleep must be finite and > 0 s, got {self.sleep_s}")
        self._rng = np.random.default_rng([self.seed, 3])

    @property
    def sleep_ns(self) -> int:
        """The idle sleep, ns."""
        return round(self.sleep_s * 1e9)

    def phase_ns(self) -> int:
        """A poll phase for a new connection: uniform in [0, sleep), ns (seeded)."""
        return int(self._rng.integers(0, self.sleep_ns))

    def run(self, port: ReaderPort, until_ns: int, stop: Callable[[], bool] | None = None) -> None:
        """Look, read or sleep until the port's clock passes ``until_ns`` (or ``stop()``)."""
        sleep = self.sleep_ns
        while stop is None or not stop():
            now = port.now_ns()
            if now > until_ns:
                return
            if not port.read_available(now):
                port.sleep_ns(sleep)


class VirtualPort(Generic[Item]):
    """The reader's port on the virtual clock: items with their socket arrival times (ns,
    in order); "available" means arrived by the clock's time. Items read are handed to
    ``deliver(items, read_ns)``.
    """

    def __init__(self, deliver: Callable[[list[Item], list[int]], None]) -> None:
        self._deliver = deliver
        self._items: deque[tuple[int, Item]] = deque()
        self.clock_ns = -(2**62)

    def now_ns(self) -> int:
        return self.clock_ns

    def sleep_ns(self, ns: int) -> None:
        self.clock_ns += ns

    def start(self, at_ns: int) -> None:
        """A new connection: the reader's first look is at ``at_ns``; nothing is queued."""
        self._items.clear()
        self.clock_ns = int(at_ns)

    def add(self, items: Sequence[Item], arrivals_ns: Sequence[int]) -> None:
        """Items that reach the socket at ``arrivals_ns`` (non-decreasing)."""
        self._items.extend(zip((int(a) for a in arrivals_ns), items, strict=True))

    def read_available(self, now_ns: int) -> bool:
        items = self._items
        if not items or items[0][0] > now_ns:
            return False
        got = []
        while items and items[0][0] <= now_ns:
            got.append(items.popleft()[1])
        self._deliver(got, [now_ns] * len(got))
        return True

    def drop_all(self) -> int:
        """The connection is gone: what was not read yet is lost; returns how many."""
        n = len(self._items)
        self._items.clear()
        return n


def wall_sleep_ns(ns: int) -> None:
    """Sleep ``ns`` on the wall clock (the live reader's idle sleep)."""
    time.sleep(ns * 1e-9)
