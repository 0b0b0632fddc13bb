"""Raw messages of a log: per topic, the undecoded payloads in one buffer plus log times.

Every container reader (MCAP, rosbag2, ROS 1 bag) fills :class:`RawTopic` objects; the
decoders in :mod:`uwval.io.fastdecode` / :mod:`uwval.io.decode` then work on whole topics.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

U8 = NDArray[np.uint8]
I64 = NDArray[np.int64]


class TruncatedLogWarning(UserWarning):
    """A log ended early (e.g. the recorder was killed); intact messages were recovered."""


def load_yaml(text: str) -> Any:
    """Parse YAML safely with ruamel.yaml (a rosbags dependency, so always installed)."""
    from ruamel.yaml import YAML

    return YAML(typ="safe", pure=True).load(text)


def norm_topic(name: str) -> str:
    """Topic names compare with one leading slash: ``groundtruth`` == ``/groundtruth``."""
    return "/" + name.strip("/")


@dataclass(frozen=True)
class TopicInfo:
    """One topic of a log: name, ROS type (pkg/msg/Type), message count, log-time span (ns)."""

    name: str
    type: str
    count: int
    start_ns: int
    end_ns: int


@dataclass
class RawTopic:
    """All messages of one topic (possibly from several connections or files).

    ``buf`` holds the payloads; message i is ``buf[offset[i] : offset[i] + length[i]]``,
    logged (received) at ``log_time[i]`` ns. ``encoding`` is ``"cdr"`` or ``"ros1"``;
    ``msgdef`` is the message definition text from the log, for types rosbags lacks.
    """

    name: str
    msgtype: str
    encoding: str
    msgdef: str = ""
    log_time: I64 = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    buf: U8 = field(default_factory=lambda: np.zeros(0, dtype=np.uint8))
    offset: I64 = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    length: I64 = field(default_factory=lambda: np.zeros(0, dtype=np.int64))

    def __len__(self) -> int:
        return int(self.log_time.shape[0])

    def payload(self, i: int) -> bytes:
        o = int(self.offset[i])
        return self.buf[o : o + int(self.length[i])].tobytes()

    def info(self) -> TopicInfo:
        n = len(self)
        return TopicInfo(
            self.name,
            self.msgtype,
            n,
            int(self.log_time.min()) if n else 0,
            int(self.log_time.max()) if n else 0,
        )


class TopicBuilder:
    """Collects segments (a buffer + offsets/lengths/log times into it) for one topic."""

    def __init__(self, name: str, msgtype: str, encoding: str, msgdef: str = "") -> None:
        self.name, self.msgtype, self.encoding, self.msgdef = name, msgtype, encoding, msgdef
        self._bufs: list[U8] = []
        self._offs: list[I64] = []
        self._lens: list[I64] = []
        self._times: list[I64] = []

    def add(self, buf: U8, offset: I64, length: I64, log_time: I64) -> None:
        """Add messages ``buf[offset[i] : offset[i] + length[i]]`` (bounds are checked)."""
        if (
            offset.size
            and length.any()
            and (
                int(offset.min()) < 0
                or int(length.min()) < 0
                or int((offset + length).max()) > buf.shape[0]
            )
        ):
            raise ValueError(f"topic {self.name}: a message reaches outside its chunk")
        if offset.size:
            self._bufs.append(buf)
            self._offs.append(offset.astype(np.int64, copy=False))
            self._lens.append(length.astype(np.int64, copy=False))
            self._times.append(log_time.astype(np.int64, copy=False))

    def drop_last_from(self, buf: U8) -> None:
        """Forget segments added from ``buf`` (a chunk whose index turned out damaged)."""
        while self._bufs and self._bufs[-1] is buf:
            for lst in (self._bufs, self._offs, self._lens, self._times):
                lst.pop()

    def add_payloads(self, payloads: list[bytes], log_time: list[int]) -> None:
        """Add per-message byte strings (readers that hand out one message at a time)."""
        if not payloads:
            return
        lens = np.fromiter((len(p) for p in payloads), dtype=np.int64, count=len(payloads))
        offs = np.zeros_like(lens)
        np.cumsum(lens[:-1], out=offs[1:])
        self.add(
            np.frombuffer(b"".join(payloads), dtype=np.uint8),
            offs,
            lens,
            np.asarray(log_time, dtype=np.int64),
        )

    def build(self) -> RawTopic:
        topic = RawTopic(self.name, self.msgtype, self.encoding, self.msgdef)
        if not self._bufs:
            return topic
        if len(self._bufs) == 1:
            buf = self._bufs[0]
            offs = self._offs[0]
        else:
            # Keep only the bytes the messages use (chunks also hold other topics).
            parts: list[U8] = []
            new_offs: list[I64] = []
            base = 0
            for b, o, ln in zip(self._bufs, self._offs, self._lens, strict=True):
                lo = int(o.min())
                hi = int((o + ln).max())
                parts.append(b[lo:hi])
                new_offs.append(o - lo + base)
                base += hi - lo
            buf = np.concatenate(parts)
            offs = np.concatenate(new_offs)
        topic.buf = buf
        topic.offset = offs
        topic.length = np.concatenate(self._lens)
        topic.log_time = np.concatenate(self._times)
        return topic


@dataclass
class RawLog:
    """What a container reader returns: topics present, and the raw messages asked for."""

    path: Path
    topics: list[TopicInfo]
    raw: dict[str, RawTopic]  # key: normalised topic name
    lost_bytes: int = 0
    notes: list[str] = field(default_factory=list)

    def warn_lost(self) -> None:
        if self.lost_bytes:
            warnings.warn(
                f"{self.path}: log is truncated; recovered the intact messages, "
                f"{self.lost_bytes} bytes at the end were lost",
                TruncatedLogWarning,
                stacklevel=3,
            )


def one_line(exc: BaseException) -> str:
    """An exception's message on one line (YAML, sqlite and pandas errors span several)."""
    return " ".join(str(exc).split()) or type(exc).__name__
