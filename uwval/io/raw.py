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


def _contiguous(buf: U8, offset: I64, length: I64) -> bool:
    """Whether the messages tile ``buf`` exactly, in order (nothing to compact)."""
    n = offset.shape[0]
    if int(length.sum()) != buf.shape[0] or int(offset[0]) != 0:
        return False
    return n < 2 or bool(np.array_equal(offset[1:], offset[:-1] + length[:-1]))


def compact(buf: U8, offset: I64, length: I64) -> tuple[U8, I64]:
    """Copy only the messages' bytes out of ``buf`` (a decompressed chunk holding other
    topics too): returns the new buffer and the messages' offsets in it.

    Equal-length messages (the usual case for one pose topic) are copied as rows through
    :func:`uwval.io.fastdecode.gather` (strided, memcpy speed); others byte-index by byte.
    """
    from uwval.io.fastdecode import gather

    n = offset.shape[0]
    if n == 0:
        return buf[:0].copy(), offset
    if _contiguous(buf, offset, length):
        return buf, offset
    width = int(length[0])
    if bool((length == width).all()):
        out = gather(buf, offset, width).reshape(-1)
        return out, np.arange(n, dtype=np.int64) * width
    new_off = np.zeros(n, dtype=np.int64)
    np.cumsum(length[:-1], out=new_off[1:])
    total = int(length.sum())
    idx = np.repeat(offset - new_off, length) + np.arange(total, dtype=np.int64)
    return buf[idx], new_off


class TopicBuilder:
    """Collects one topic's messages, segment by segment (e.g. a batch of chunks each).

    Each segment is compacted when added (only this topic's bytes are kept, never the whole
    decompressed chunk), so memory is bounded by the selected topics, not by the log.
    """

    def __init__(self, name: str, msgtype: str, encoding: str, msgdef: str = "") -> None:
        self.name, self.msgtype, self.encoding, self.msgdef = name, msgtype, encoding, msgdef
        self._bufs: list[U8] = []
        self._offs: list[I64] = []
        self._lens: list[I64] = []
        self._times: list[I64] = []
        #: per segment: > 0 when it is fixed-width rows (offsets i * width, built lazily)
        self._width: list[int] = []
        self.dropped: dict[str, int] = {}

    def __len__(self) -> int:
        return sum(int(t.shape[0]) for t in self._times)

    def take_rows(self, buf: U8, starts: I64, width: int, log_time: I64) -> None:
        """Add the messages ``buf[starts[i] : starts[i] + width]`` (bounds checked by the
        caller), logged at ``log_time`` ns: one row gather, one segment."""
        from uwval.io.fastdecode import gather

        self.add_rows(gather(buf, starts, width), log_time)

    def drop(self, cause: str, n: int) -> None:
        """Count ``n`` messages of this topic lost for ``cause``."""
        if n > 0:
            self.dropped[cause] = self.dropped.get(cause, 0) + int(n)

    def add(
        self,
        buf: U8,
        offset: I64,
        length: I64,
        log_time: I64,
        *,
        copy: bool = True,
    ) -> None:
        """Add messages ``buf[offset[i] : offset[i] + length[i]]`` (bounds are checked).

        ``copy`` compacts them out of ``buf`` now (``False``: ``buf`` holds only them
        already).
        """
        offset = offset.astype(np.int64, copy=False)
        length = length.astype(np.int64, copy=False)
        if not offset.size:
            return
        if length.any() and (
            int(offset.min()) < 0
            or int(length.min()) < 0
            or int((offset + length).max()) > buf.shape[0]
        ):
            raise ValueError(f"topic {self.name}: a message reaches outside its chunk")
        if copy and length.any():
            buf, offset = compact(buf, offset, length)
        elif not length.any():
            buf, offset = buf[:0], np.zeros_like(offset)
        self._bufs.append(buf)
        self._offs.append(offset)
        self._lens.append(length)
        self._times.append(log_time.astype(np.int64, copy=False))
        self._width.append(0)

    def add_rows(self, rows: U8, log_time: I64) -> None:
        """Add messages of one length: row i of the (N, width) ``rows`` (owned from now on;
        a copy already made out of the chunk) is the payload logged at ``log_time[i]`` ns."""
        n, width = rows.shape
        if not n:
            return
        empty = np.zeros(0, dtype=np.int64)
        self._bufs.append(rows.reshape(-1))
        self._offs.append(empty)
        self._lens.append(empty)
        self._times.append(log_time.astype(np.int64, copy=False))
        self._width.append(int(width))

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
            copy=False,
        )

    def add_topic(self, part: RawTopic) -> None:
        """Append an already built topic (another connection or file of the same topic)."""
        self.add(part.buf, part.offset, part.length, part.log_time, copy=False)
        for cause, n in part.dropped.items():
            self.drop(cause, n)

    def build(self) -> RawTopic:
        """One RawTopic: the segments' buffers concatenated, offsets rebased."""
        topic = RawTopic(self.name, self.msgtype, self.encoding, self.msgdef)
        topic.dropped = dict(self.dropped)
        if not self._bufs:
            return topic
        topic.buf = self._bufs[0] if len(self._bufs) == 1 else np.concatenate(self._bufs)
        topic.log_time = self._times[0] if len(self._times) == 1 else np.concatenate(self._times)
        n = int(topic.log_time.shape[0])
        w = self._width[0]
        if w > 0 and all(x == w for x in self._width):  # one width: no per-segment arrays
            topic.offset = np.arange(n, dtype=np.int64) * w
            topic.length = np.full(n, w, dtype=np.int64)
            return topic
        offs, lens = [], []
        base = 0
        for b, o, ln, t, wd in zip(
            self._bufs, self._offs, self._lens, self._times, self._width, strict=True
        ):
            if wd > 0:
                m = int(t.shape[0])
                o = np.arange(m, dtype=np.int64) * wd
                ln = np.full(m, wd, dtype=np.int64)
            offs.append(o + base if base else o)
            lens.append(ln)
            base += int(b.shape[0])
        topic.offset = offs[0] if len(offs) == 1 else np.concatenate(offs)
        topic.length = lens[0] if len(lens) == 1 else np.concatenate(lens)
        return topic


def merge_infos(infos: Iterable[TopicInfo]) -> list[TopicInfo]:
    """One TopicInfo per topic name (several connections, channels or files of one topic):
    counts added, spans joined over the parts that have messages; first non-empty type."""
    out: dict[str, TopicInfo] = {}
    for i in infos:
        o = out.get(i.name)
        if o is None:
            out[i.name] = i
            continue
        have = [x for x in (o, i) if x.count]
        out[i.name] = TopicInfo(
            i.name,
            o.type or i.type,
            o.count + i.count,
            min(x.start_ns for x in have) if have else 0,
            max(x.end_ns for x in have) if have else 0,
        )
    return list(out.values())


def merge_topics(parts: Iterable[RawTopic]) -> dict[str, RawTopic]:
    """Join RawTopics that share a name (several connections, channels or files)."""
    groups: dict[str, list[RawTopic]] = {}
    for t in parts:
        groups.setdefault(t.name, []).append(t)
    out: dict[str, RawTopic] = {}
    for name, ts in groups.items():
        if len(ts) == 1:
            out[name] = ts[0]
            continue
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
