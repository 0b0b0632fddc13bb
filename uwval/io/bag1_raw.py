"""ROS 1 bag (v2.0) reader: a numpy walk of the bag's index, one decompress per chunk.

The index section lists connections and chunks (ChunkInfo); the IndexData records after each
chunk give every message's time and offset in it, checked against the records they point at
(op, connection, time, bounds) for the topics read, and turned into payload positions by
numpy gathers. A chunk whose index disagrees is read by walking its records; a damaged chunk
is dropped and counted by cause; a bag without a usable index (its recorder was killed) is
read by a walk over its records and reported.
"""

from __future__ import annotations

import bz2
import contextlib
import mmap
import struct
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from uwval.errors import LogReadError
from uwval.io.fastdecode import gather
from uwval.io.raw import (
    RawLog,
    TopicBuilder,
    TopicInfo,
    merge_infos,
    merge_topics,
    norm_topic,
    one_line,
    unaligned,
)
from uwval.io.ros import normalize_type_name

MAGIC = b"#ROSBAG V2.0\n"
OP_MSG_DATA, OP_BAG_HEADER, OP_INDEX_DATA, OP_CHUNK, OP_CHUNK_INFO, OP_CONNECTION = range(2, 8)
_U32 = struct.Struct("<I")
I64 = NDArray[np.int64]
#: What a damaged record raises while it is parsed (a field missing, cut, not UTF-8...).
DAMAGE = (LogReadError, KeyError, IndexError, ValueError, struct.error)


class BagFormatError(LogReadError):
    """A record of the bag does not have the structure of the ROS bag 2.0 format."""


def _fields(b: Any, pos: int, end: int) -> dict[str, bytes]:
    """The ``name=value`` fields of a record header in ``b[pos:end]``."""
    out: dict[str, bytes] = {}
    while pos + 4 <= end:
        (n,) = _U32.unpack_from(b, pos)
        name, sep, value = bytes(b[pos + 4 : pos + 4 + n]).partition(b"=")
        if not sep or pos + 4 + n > end:
            raise BagFormatError("malformed record header field")
        out[name.decode()] = value
        pos += 4 + n
    return out


def _record(b: Any, pos: int, size: int) -> tuple[dict[str, bytes], int, int, int]:
    """(header fields, data start, data length, next record position) of the record at pos."""
    if pos + 4 > size:
        raise BagFormatError(f"record at byte {pos} is cut off")
    (hl,) = _U32.unpack_from(b, pos)
    if pos + 8 + hl > size:
        raise BagFormatError(f"record header at byte {pos} is cut off")
    hdr = _fields(b, pos + 4, pos + 4 + hl)
    (dl,) = _U32.unpack_from(b, pos + 4 + hl)
    ds = pos + 8 + hl
    if ds + dl > size:
        raise BagFormatError(f"record data at byte {pos} is cut off")
    return hdr, ds, dl, ds + dl


def _u32(v: bytes) -> int:
    return int(_U32.unpack(v[:4])[0])


def _conn(b: Any, hdr: dict[str, bytes], ds: int, dl: int) -> tuple[int, str, str, str]:
    """A connection record's id and topic (header), type and definition (data); text that
    is not UTF-8, or no md5sum, is damage (rosbags refuses both too)."""
    d = _fields(b, ds, ds + dl)
    d["md5sum"].decode()
    text = (hdr["topic"], d["type"], d["message_definition"])
    return (_u32(hdr["conn"]), *(x.decode() for x in text))  # type: ignore[return-value]


def _decompress(hdr: dict[str, bytes], data: bytes) -> bytes:
    """A chunk's records; :class:`BagFormatError` (one line) when they cannot be had."""
    comp, size = hdr["compression"].decode(), _u32(hdr["size"])
    if comp not in ("none", "bz2", "lz4"):
        raise BagFormatError(f"unsupported chunk compression {comp!r}")
    try:
        if comp == "bz2":
            data = bz2.decompress(data)
        elif comp == "lz4":
            import lz4.frame

            data = bytes(lz4.frame.decompress(data))
    except Exception as exc:  # bz2: OSError/ValueError; lz4: RuntimeError
        raise BagFormatError(f"{comp} data cannot be decompressed ({one_line(exc)})") from exc
    if len(data) != size:
        raise BagFormatError(f"chunk decompresses to {len(data)} bytes, its header says {size}")
    return data


def scan_bag1(path: Path, topics: Iterable[str] | None, *, times_only: bool = False) -> RawLog:
    """Topic infos and raw messages of ``topics`` (None: all; ``times_only``: log times
    alone, no payloads) of a ROS 1 bag."""
    want = None if topics is None else {norm_topic(t) for t in topics}
    with open(path, "rb") as fh:
        mm = mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ)
    try:
        return _Bag(path, mm, want, times_only).read()
    finally:
        with contextlib.suppress(BufferError):  # an empty payload may still view the map
            mm.close()


@dataclass
class _Bag:
    """One read of a bag (see :func:`scan_bag1`): connections, builders and log times."""

    path: Path
    mm: mmap.mmap
    want: set[str] | None
    times_only: bool
    conns: dict[int, tuple[str, str]] = field(default_factory=dict)  # id: topic, type
    builders: dict[int, TopicBuilder] = field(default_factory=dict)
    times: dict[int, list[I64]] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)

    def read(self) -> RawLog:
        """The whole bag, through its index when it has a sound one."""
        size = len(self.mm)
        if self.mm[: len(MAGIC)] != MAGIC:
            raise LogReadError(f"{self.path}: not a ROS bag v2.0 (bad magic bytes at offset 0)")
        try:
            hdr, _ds, _dl, first = _record(self.mm, len(MAGIC), size)
            if hdr.get("op", b"\0")[:1] != bytes([OP_BAG_HEADER]):
                raise BagFormatError("first record is not the bag header")
            index_pos = struct.unpack("<Q", hdr["index_pos"][:8])[0]
            counts = (_u32(hdr["conn_count"]), _u32(hdr["chunk_count"]))
        except DAMAGE as exc:  # nothing can be located without the bag header
            raise LogReadError(f"{self.path}: cannot read ROS 1 bag: {one_line(exc)}") from exc
        if index_pos == 0 or index_pos >= size:  # never closed (recorder killed) or cut short
            return self._walk(first, "no index: the writer did not finish")
        try:
            chunks = self._index(index_pos, counts)
        except DAMAGE as exc:
            self.conns, self.builders, self.times = {}, {}, {}
            self.warnings.append(
                f"{self.path}: the index section at byte {index_pos} is damaged ({one_line(exc)}); "
                "read by a linear walk over the records"
            )
            return self._walk(first, "")
        for cp in sorted(chunks):
            try:
                self._chunk(cp, chunks[cp])
            except DAMAGE as exc:
                lost = chunks[cp]
                self._lost(cp, lost, lost, "damaged_chunk", f" is damaged ({one_line(exc)})")
        return self._log(0, "")

    def _index(self, pos: int, counts: tuple[int, int]) -> dict[int, dict[int, int]]:
        """Connections, and per chunk position its message count per connection."""
        chunks: dict[int, dict[int, int]] = {}
        while pos < len(self.mm):
            h, ds, dl, pos = _record(self.mm, pos, len(self.mm))
            if h["op"][0] == OP_CONNECTION:
                self._connection(*_conn(self.mm, h, ds, dl))
            elif h["op"][0] == OP_CHUNK_INFO:
                if dl % 8 or _u32(h["count"]) * 8 != dl or not {"start_time", "end_time"} <= set(h):
                    raise BagFormatError(f"chunk info at byte {ds} is malformed")
                pairs = np.frombuffer(self.mm[ds : ds + dl], dtype="<u4").reshape(-1, 2)
                chunks[struct.unpack("<Q", h["chunk_pos"][:8])[0]] = dict(pairs.tolist())
        if (len(self.conns), len(chunks)) != counts:
            raise BagFormatError("index section does not match the bag header counts")
        return chunks

    def _connection(self, cid: int, topic: str, msgtype: str, msgdef: str) -> None:
        name, msgtype = norm_topic(topic), normalize_type_name(msgtype)
        self.conns[cid] = (name, msgtype)
        self.times.setdefault(cid, [])
        if cid not in self.builders and (self.want is None or name in self.want):
            self.builders[cid] = TopicBuilder(name, msgtype, "ros1", msgdef)

    def _chunk(self, cp: int, expected: dict[int, int]) -> None:
        """One chunk and its IndexData records into the builders (checked against each other)."""
        size = len(self.mm)
        h, ds, dl, pos = _record(self.mm, cp, size)
        if h["op"][0] != OP_CHUNK:
            raise BagFormatError(f"no chunk record at byte {cp}")
        entries: dict[int, NDArray[np.uint32]] | None = {}
        found: dict[int, NDArray[np.uint32]] = {}
        try:  # IndexData records follow the chunk: per connection, (sec, nsec, offset)
            while pos + 4 <= size and len(found) < len(expected):
                ih, ids, idl, nxt = _record(self.mm, pos, size)
                if ih["op"][0] != OP_INDEX_DATA:
                    break
                if idl != 12 * _u32(ih["count"]):
                    raise BagFormatError(f"index data at byte {pos} has the wrong size")
                found[_u32(ih["conn"])] = np.frombuffer(self.mm[ids : ids + idl], "<u4").reshape(
                    -1, 3
                )
                pos = nxt
            entries = found
            if {c: len(e) for c, e in found.items()} != expected:
                raise BagFormatError("its IndexData records disagree with the chunk info")
        except DAMAGE as exc:
            self.warnings.append(
                f"{self.path}: index data after the ROS 1 chunk at byte {cp} is damaged "
                f"({one_line(exc)}); read the chunk by walking its records"
            )
            entries = None
        wanted = [c for c in expected if c in self.builders]
        if entries is not None and (self.times_only or not wanted):
            for cid, e in entries.items():  # times from the index alone
                self._take(cid, None, e[:, 0].astype(np.int64) * 1_000_000_000 + e[:, 1])
            return
        data = _decompress(h, bytes(self.mm[ds : ds + dl]))
        buf = np.frombuffer(data, dtype=np.uint8)
        checks = {c: _index_ok(buf, c, entries[c]) for c in wanted} if entries else {}
        if entries is not None and all(checks.values()):
            for cid, e in entries.items():
                self._take(cid, buf, e[:, 0].astype(np.int64) * 1_000_000_000 + e[:, 1], e)
            return
        bad = next((c for c, ok in checks.items() if ok is False), None)
        if bad is not None:  # (None: headers of varying layout, read by the walk below)
            self.warnings.append(
                f"{self.path}: the index of the ROS 1 chunk at byte {cp} disagrees with its "
                f"records (connection {bad}); read the chunk by walking its records"
            )
        before = {c: len(self.times.get(c, [])) for c in expected}  # arrays, not messages
        stop, _at = self._records(data, 0)
        got = {c: sum(x.size for x in self.times.get(c, [])[before[c] :]) for c in expected}
        lost = {c: n - got[c] for c, n in expected.items()}
        if stop or any(n > 0 for n in lost.values()):
            why = f": {stop or 'records missing'}"
            self._lost(
                cp, expected, {c: n for c, n in lost.items() if n > 0}, "damaged_record", why
            )

    def _take(self, cid: int, buf: Any, t: I64, e: NDArray[np.uint32] | None = None) -> None:
        """Log times of ``cid``'s messages; their payloads too when it is read (``e``: the
        index entries locating them in ``buf``)."""
        self.times.setdefault(cid, []).append(t)
        b = self.builders.get(cid)
        if b is None:
            return
        if buf is None or e is None:
            z = np.zeros_like(t)
            b.add(np.zeros(0, np.uint8), z, z, t, copy=False)
            return
        u32 = unaligned(buf, "<u4")
        rec = e[:, 2].astype(np.int64)
        hl = u32[rec].astype(np.int64)
        dlen = u32[rec + 4 + hl].astype(np.int64)
        width = int(dlen[0]) if len(dlen) else 0
        if width > 0 and int(dlen.min()) == int(dlen.max()):  # one length: a pose topic
            b.take_rows(buf, rec + 8 + hl, width, t)
        else:
            b.add(buf, rec + 8 + hl, dlen, t)

    def _records(self, b: Any, pos: int, end: int | None = None) -> tuple[str, int]:
        """Walk the records of ``b`` from ``pos``: connections registered, messages taken
        (payloads of read topics). Returns why the walk stopped early ("" at the end) and
        where."""
        end = len(b) if end is None else end
        found: dict[int, tuple[list[int], list[int], list[int]]] = {}
        stop = ""
        while pos < end:
            try:
                h, ds, dl, nxt = _record(b, pos, end)
                op = h["op"][0]
                if op == OP_CONNECTION:
                    self._connection(*_conn(b, h, ds, dl))
                elif op == OP_MSG_DATA:
                    m = found.setdefault(_u32(h["conn"]), ([], [], []))
                    m[0].append(ds)
                    m[1].append(dl)
                    m[2].append(_u32(h["time"]) * 1_000_000_000 + _u32(h["time"][4:]))
                elif op == OP_CHUNK:
                    self._flush(b, found)
                    found = {}
                    stop, _ = self._records(_decompress(h, bytes(b[ds : ds + dl])), 0)
                    if stop:
                        raise BagFormatError(stop)
            except DAMAGE as exc:
                stop = f"record at byte {pos} is damaged ({one_line(exc)})"
                break
            pos = nxt
        self._flush(b, found)
        return stop, pos

    def _flush(self, b: Any, found: dict[int, tuple[list[int], list[int], list[int]]]) -> None:
        buf = np.frombuffer(b, dtype=np.uint8)
        for cid, (offs, lens, stamps) in found.items():
            t = np.asarray(stamps, dtype=np.int64)
            self.times.setdefault(cid, []).append(t)
            if cid in self.builders:
                keep = 0 if self.times_only else 1  # times only: no payload bytes
                o, n = np.asarray(offs, np.int64) * keep, np.asarray(lens, np.int64) * keep
                self.builders[cid].add(buf, o, n, t)

    def _lost(
        self, cp: int, expected: dict[int, int], lost: dict[int, int], cause: str, why: str
    ) -> None:
        """Count ``lost`` messages (per connection) of the chunk at ``cp``, which held
        ``expected``, as dropped for ``cause``, and say so."""
        total = sum(expected.values())
        for cid, n in lost.items():
            if cid in self.builders:
                self.builders[cid].drop(cause, n)
        parts = ", ".join(
            f"{n} on {self.builders[c].name}" for c, n in lost.items() if c in self.builders
        )
        self.warnings.append(
            f"{self.path}: ROS 1 chunk at byte {cp}{why}; {sum(lost.values())} of its {total} "
            "message(s) could not be read" + (f" ({parts})" if parts else "")
        )

    def _walk(self, pos: int, unclean: str) -> RawLog:
        """Read a bag without a usable index by walking its records from ``pos``; the walk
        stops at the first damaged record, the bytes from it on are reported as lost."""
        stop, at = self._records(self.mm, pos)
        lost = len(self.mm) - at if stop else 0
        if lost and not unclean:
            self.warnings.append(
                f"{self.path}: the linear walk stopped: {stop}; the {lost} bytes from there "
                "on could not be read"
            )
            lost = 0
        return self._log(lost, unclean)

    def _log(self, lost_bytes: int, unclean: str) -> RawLog:
        infos = []
        for cid, (name, msgtype) in self.conns.items():
            t = [x for x in self.times.get(cid, []) if x.size]
            lo, hi = (min(int(x.min()) for x in t), max(int(x.max()) for x in t)) if t else (0, 0)
            infos.append(TopicInfo(name, msgtype, sum(x.size for x in t), lo, hi))
        topics = merge_topics(b.build() for b in self.builders.values())
        log = RawLog(self.path, merge_infos(infos), topics, lost_bytes, [], self.warnings, unclean)
        if not infos:
            log.notes.append("bag has no connections and no messages")
        return log


def _index_ok(buf: NDArray[np.uint8], cid: int, e: NDArray[np.uint32]) -> bool | None:
    """Whether every IndexData entry of ``cid`` points at a MessageData record of ``cid``
    with the entry's time, lying inside the chunk (vectorised: every header is compared with
    the first one's bytes, the time field with the index's times); None when the headers
    differ in layout (the chunk is then read by walking its records)."""
    if not len(e):
        return True
    size = buf.shape[0]
    rec = e[:, 2].astype(np.int64)
    if int(rec.max()) + 8 > size:
        return False
    u32 = unaligned(buf, "<u4")
    hl = u32[rec].astype(np.int64)
    if int(hl.min()) != int(hl.max()):
        return None
    if int((rec + 8 + hl).max()) > size:
        return False
    h0 = int(hl[0])
    heads = gather(buf, rec + 4, h0)
    try:
        fields = _fields(heads[0], 0, h0)
    except DAMAGE:
        return False
    tpos = bytes(heads[0]).find(b"time=")
    if (
        fields.get("op", b"")[:1] != bytes([OP_MSG_DATA])
        or fields.get("conn", b"")[:4] != _U32.pack(cid)
        or tpos < 0
        or tpos + 13 > h0
    ):
        return False
    mask = np.ones(h0, dtype=bool)
    mask[tpos + 5 : tpos + 13] = False
    if not bool((heads[:, mask] == heads[0, mask]).all()):
        return None
    stamp = np.ascontiguousarray(heads[:, tpos + 5 : tpos + 13]).view("<u4").reshape(-1, 2)
    dlen = u32[rec + 4 + hl].astype(np.int64)
    return bool(np.array_equal(stamp, e[:, :2]) and int((rec + 8 + hl + dlen).max()) <= size)
