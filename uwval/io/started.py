"""Reads begun on a thread of their own before anyone asks for them (:mod:`uwval.io.early`),
each taken only by the read that would make exactly it.

A started read maps its file read-only and runs one function of the map (a C call that
releases the GIL: the thread then overlaps the imports of ``uwval compare``). It is kept
under the file's identity (device, inode, size, modification time) and the read's arguments;
:meth:`StartedReads.take` gives its result to the read that names the same, unchanged file
with the same arguments, and drops every other: a read happened, they are of no use.
Nothing here imports numpy.
"""

from __future__ import annotations

import mmap
import os
import threading
from collections.abc import Callable
from pathlib import Path
from typing import Generic, TypeVar

T = TypeVar("T")


class StartedRead(Generic[T]):
    """``read`` of the read-only map of ``path``, on its own (daemon) thread."""

    def __init__(self, path: Path, read: Callable[[mmap.mmap], T], name: str) -> None:
        self.path, self.read = path, read
        self.result: T | None = None
        self.thread = threading.Thread(target=self._run, name=name, daemon=True)

    def _run(self) -> None:
        try:
            with (
                open(self.path, "rb") as f,
                mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) as mm,
            ):
                self.result = self.read(mm)
        except Exception:  # the read will read the file itself, and report what is wrong
            self.result = None


class StartedReads(dict[tuple[object, ...], StartedRead[T]]):
    """The reads started and not taken yet, by file identity and arguments."""

    @staticmethod
    def key(path: Path, args: tuple[object, ...]) -> tuple[object, ...]:
        st = os.stat(path)
        return (st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns, *args)

    def start(
        self, path: Path, args: tuple[object, ...], read: Callable[[mmap.mmap], T], name: str
    ) -> None:
        """Run ``read`` of the map of ``path`` on its own thread, kept under ``args``."""
        run = StartedRead(path, read, name)
        self[self.key(path, args)] = run
        run.thread.start()

    def take(self, path: Path, args: tuple[object, ...]) -> T | None:
        """The result of the read started of ``path`` (unchanged since) with exactly
        ``args``, waiting for it to end; None when there is none (or it failed). Every other
        started read is dropped."""
        if not self:
            return None
        try:
            key: tuple[object, ...] | None = self.key(path, args)
        except OSError:
            key = None
        run = self.pop(key, None) if key is not None else None
        self.clear()
        if run is None:
            return None
        run.thread.join()
        return run.result
