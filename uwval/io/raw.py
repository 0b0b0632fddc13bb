"""Raw messages of a log: per topic, the undecoded payloads in one buffer plus log times.

Every container reader (MCAP, rosbag2, ROS 1 bag) fills :class:`RawTopic` objects; the
decoders in :mod:`uwval.io.fastdecode` / :mod:`uwval.io.decode` then work on whole topics.
"""

from __future__ import annotations

import warnings
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from uwval.io.names import norm_topic as norm_topic  # re-exported: the readers import it here

U8 = NDArray[np.uint8]
I64 = NDArray[np.int64]
#: bytes, memoryview, mmap or a uint8 ndarray: whatever struct reads and slicing copies
#: (typeshed's ReadableBuffer cannot be sliced, and numpy's stubs do not make arrays one).
Buffer = Any


class LogWarning(UserWarning):
    """Something in a log was damaged or missing; what could be read was read, and counted."""


class TruncatedLogWarning(LogWarning):
    """A log ended early or was not closed cleanly (e.g. the recorder was killed); the intact
    messages were recovered."""


def load_yaml(text: str) -> Any:
    """Parse YAML safely with ruamel.yaml (a rosbags dependency, so always installed)."""
    from ruamel.yaml import YAML

    return YAML(typ="safe", pure=True).load(text)


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
    ``dropped`` counts, by cause, messages of this topic the container held but that could
    not be recovered (a chunk failing its CRC, a zeroed region...).
    """

    name: str
    msgtype: str
    encoding: str
    msgdef: str = ""
    log_time: I64 = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    buf: U8 = field(default_factory=lambda: np.zeros(0, dtype=np.uint8))
    offset: I64 = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    length: I64 = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    dropped: dict[str, int] = field(default_factory=dict)

    def __len__(self) -> int:
        return int(self.log_time.shape[0])

    def payload(self, i: int) -> bytes:
        """Message ``i``'s bytes."""
        return self.buf[int(self.offset[i]) :][: int(self.length[i])].tobytes()

    def info(self) -> TopicInfo:
        """Name, type, count and log-time span (ns) of the topic."""
        t = self.log_time
        span = (int(t.min()), int(t.max())) if len(t) else (0, 0)
        return TopicInfo(self.name, self.msgtype, len(self), *span)


def compact(buf: U8, offset: I64, length: I64) -> tuple[U8, I64]:
    """Copy only the messages' bytes out of ``buf`` (a decompressed chunk holding other
    topics too): the new buffer and the messages' offsets in it. Equal lengths (one pose
    topic) are copied as rows (:func:`uwval.io.fastdecode.gather`, strided, memcpy speed)."""
    from uwval.io.fastdecode import gather

    n = offset.shape[0]
    if n and bool((length == length[0]).all()):
        return gather(buf, offset, int(length[0])).reshape(-1), np.arange(n) * length[0]
    new_off = np.concatenate(([0], np.cumsum(length)[:-1])).astype(np.int64)
    idx = np.repeat(offset - new_off, length) + np.arange(int(length.sum()), dtype=np.int64)
    return buf[idx], new_off


class TopicBuilder:
    """Collects one topic's messages, segment by segment (a run of chunks each). Only this
    topic's bytes are kept, never a whole decompressed chunk: memory is bounded by the
    selected topics, not by the log."""

    def __init__(self, name: str, msgtype: str, encoding: str, msgdef: str = "") -> None:
        self.name, self.msgtype, self.encoding, self.msgdef = name, msgtype, encoding, msgdef
        #: per segment: payload buffer, offsets, lengths, log times (ns), and a width > 0
        #: when it is fixed-width rows (offsets and lengths then built in :meth:`build`)
        self._segs: list[tuple[U8, I64, I64, I64, int]] = []
        self.dropped: dict[str, int] = {}

    def __len__(self) -> int:
        return sum(int(s[3].shape[0]) for s in self._segs)

    def drop(self, cause: str, n: int) -> None:
        """Count ``n`` messages of this topic lost for ``cause``."""
        if n > 0:
            self.dropped[cause] = self.dropped.get(cause, 0) + int(n)

    def add(self, buf: U8, offset: I64, length: I64, log_time: I64, *, copy: bool = True) -> None:
        """Add messages ``buf[offset[i] : offset[i] + length[i]]`` logged at ``log_time[i]``
        ns (bounds are checked); ``copy=False``: ``buf`` holds only them already."""
        offset, length = offset.astype(np.int64, copy=False), length.astype(np.int64, copy=False)
        if not offset.size:
            return
        if length.any() and (
            int(offset.min()) < 0
            or int(length.min()) < 0
            or int((offset + length).max()) > len(buf)
        ):
            raise ValueError(f"topic {self.name}: a message reaches outside its chunk")
        if not length.any():
            buf, offset = buf[:0], np.zeros_like(offset)
        elif copy:
            buf, offset = compact(buf, offset, length)
        self._segs.append((buf, offset, length, log_time.astype(np.int64, copy=False), 0))

    def add_rows(self, rows: U8, log_time: I64) -> None:
        """Add messages of one length: row i of the (N, width) ``rows`` (owned from now on,
        a copy already made out of the chunk) is the payload logged at ``log_time[i]`` ns."""
        if rows.shape[0]:
            none = np.zeros(0, dtype=np.int64)
            times = log_time.astype(np.int64, copy=False)
            self._segs.append((rows.reshape(-1), none, none, times, int(rows.shape[1])))

    def take_rows(self, buf: U8, starts: I64, width: int, log_time: I64) -> None:
        """Add the messages ``buf[starts[i] : starts[i] + width]`` (one row gather)."""
        from uwval.io.fastdecode import gather

        self.add_rows(gather(buf, starts, width), log_time)

    def add_payloads(self, payloads: list[bytes], log_time: list[int]) -> None:
        """Add per-message byte strings (readers that hand out one message at a time)."""
        if payloads:
            lens = np.array([len(p) for p in payloads], dtype=np.int64)
            offs = np.concatenate(([0], np.cumsum(lens)[:-1])).astype(np.int64)
            data = np.frombuffer(b"".join(payloads), dtype=np.uint8)
            self.add(data, offs, lens, np.asarray(log_time, dtype=np.int64), copy=False)

    def add_topic(self, part: RawTopic) -> None:
        """Append an already built topic (another connection or file of the same topic)."""
        self.add(part.buf, part.offset, part.length, part.log_time, copy=False)
        for cause, n in part.dropped.items():
            self.drop(cause, n)

    def build(self) -> RawTopic:
        """One RawTopic: the segments' buffers concatenated, offsets rebased."""
        topic = RawTopic(self.name, self.msgtype, self.encoding, self.msgdef)
        topic.dropped = dict(self.dropped)
        if not self._segs:
            return topic
        bufs, offs, lens, times, widths = zip(*self._segs, strict=True)
        topic.buf = bufs[0] if len(bufs) == 1 else np.concatenate(bufs)
        topic.log_time = times[0] if len(times) == 1 else np.concatenate(times)
        if widths[0] > 0 and len(set(widths)) == 1:  # one width: no per-segment arrays
            topic.offset = np.arange(len(topic), dtype=np.int64) * widths[0]
            topic.length = np.full(len(topic), widths[0], dtype=np.int64)
            return topic
        base = np.cumsum([0, *(len(b) for b in bufs[:-1])])
        rows = [np.arange(len(t), dtype=np.int64) * w for t, w in zip(times, widths, strict=True)]
        topic.offset = np.concatenate(
            [(r if w else o) + at for o, r, w, at in zip(offs, rows, widths, base, strict=True)]
        )
        topic.length = np.concatenate(
            [
                np.full(len(t), w, np.int64) if w else ln
                for ln, t, w in zip(lens, times, widths, strict=True)
            ]
        )
        return topic


def merge_infos(infos: Iterable[TopicInfo]) -> list[TopicInfo]:
    """One TopicInfo per topic name (several connections, channels or files of one topic):
    counts added, spans joined over the parts that have messages; first non-empty type."""
    out: dict[str, TopicInfo] = {}
    for i in infos:
        o = out.setdefault(i.name, i)
        if o is not i:
            have = [x for x in (o, i) if x.count]
            lo, hi = (
                min((x.start_ns for x in have), default=0),
                max((x.end_ns for x in have), default=0),
            )
            out[i.name] = TopicInfo(i.name, o.type or i.type, o.count + i.count, lo, hi)
    return list(out.values())


def merge_topics(parts: Iterable[RawTopic]) -> dict[str, RawTopic]:
    """Join RawTopics that share a name (several connections, channels or files)."""
    groups: dict[str, list[RawTopic]] = {}
    for t in parts:
        groups.setdefault(t.name, []).append(t)
    out: dict[str, RawTopic] = {}
    for name, ts in groups.items():
        out[name] = ts[0]
        if len(ts) > 1:
            b = TopicBuilder(name, ts[0].msgtype, ts[0].encoding, ts[0].msgdef)
            for t in ts:
                b.add_topic(t)
            out[name] = b.build()
    return out


@dataclass
class RawLog:
    """What a container reader returns: topics present, and the raw messages asked for.

    ``lost_bytes``: bytes at the end that could not be read (a cut-off log);
    ``unclean``: why the log looks not closed cleanly (no summary / footer / metadata /
    index), or ``""``;
    ``warnings``: what else went wrong (damaged chunks, index disagreements...), each
    naming the file and the byte offset. Every stream read from the log carries them.
    """

    path: Path
    topics: list[TopicInfo]
    raw: dict[str, RawTopic]  # key: normalised topic name
    lost_bytes: int = 0
    notes: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    unclean: str = ""
    cut_detail: str = ""  # what was recovered from a record cut by the end of the file

    def truncation(self) -> str:
        """The one-line truncation / unclean-close message, or ``""``."""
        n = sum(i.count for i in self.topics)
        if self.lost_bytes:
            return (
                f"{self.path}: log is truncated (not closed cleanly); recovered the intact "
                f"messages ({n} messages), {self.lost_bytes} bytes at the end were lost"
                + (f" ({self.cut_detail})" if self.cut_detail else "")
            )
        if self.unclean:
            return (
                f"{self.path}: log was not closed cleanly ({self.unclean}); recovered "
                f"{n} messages, no bytes lost"
            )
        return ""

    def all_warnings(self) -> list[str]:
        """The truncation message (if any) then the other warnings."""
        t = self.truncation()
        return ([t] if t else []) + list(self.warnings)

    def warn_lost(self) -> None:
        """Emit every warning as a Python warning (the CLI prints them as one line each)."""
        t = self.truncation()
        if t:
            warnings.warn(t, TruncatedLogWarning, stacklevel=3)
        for w in self.warnings:
            warnings.warn(w, LogWarning, stacklevel=3)


def one_line(exc: BaseException) -> str:
    """An exception's message on one line (YAML, sqlite and pandas errors span several)."""
    return " ".join(str(exc).split()) or type(exc).__name__


def unaligned(buf: U8, dtype: str) -> NDArray[Any]:
    """A read-only view of ``buf`` whose element i is the ``dtype`` value starting at byte i
    (so ``view[offsets]`` gathers fields of records at arbitrary, unaligned offsets)."""
    itemsize = np.dtype(dtype).itemsize
    n = max(int(buf.shape[0]) - itemsize + 1, 0)
    view: NDArray[Any] = np.ndarray((n,), dtype=dtype, buffer=buf, strides=(1,))
    view.flags.writeable = False
    return view
