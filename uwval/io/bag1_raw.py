"""Fast ROS 1 bag (v2.0) scanner: per chunk, one decompress and numpy offset arithmetic.

A bag's index section lists connections and chunk positions; each chunk is followed by
IndexData records giving, per connection, every message's time and offset inside the
uncompressed chunk. From those offsets the payload positions are computed with two numpy
gathers (the record's header length, then its data length) instead of parsing every
message record in Python. Files this scanner cannot follow (unindexed, damaged) are handed
to rosbags' reader by :mod:`uwval.io.containers`, which reports the cause.
"""

from __future__ import annotations

import bz2
import mmap
import struct
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from uwval.io.fastdecode import gather
from uwval.io.raw import RawLog, RawTopic, TopicBuilder, TopicInfo, norm_topic
from uwval.io.ros import normalize_type_name

MAGIC = b"#ROSBAG V2.0\n"
OP_MSG_DATA, OP_BAG_HEADER, OP_INDEX_DATA, OP_CHUNK, OP_CHUNK_INFO, OP_CONNECTION = (
    0x02,
    0x03,
    0x04,
    0x05,
    0x06,
    0x07,
)

_U32 = struct.Struct("<I")
I64 = NDArray[np.int64]


class BagFormatError(Exception):
    """The bag does not have the structure this scanner follows (use the fallback)."""


@dataclass
class _Conn:
    id: int
    topic: str
    msgtype: str
    msgdef: str


def _fields(b: bytes | mmap.mmap, pos: int, end: int) -> dict[str, bytes]:
    out: dict[str, bytes] = {}
    while pos + 4 <= end:
        (n,) = _U32.unpack_from(b, pos)
        field = bytes(b[pos + 4 : pos + 4 + n])
        name, sep, value = field.partition(b"=")
        if not sep or pos + 4 + n > end:
            raise BagFormatError("malformed record header field")
        out[name.decode()] = value
        pos += 4 + n
    return out


def _record(b: bytes | mmap.mmap, pos: int, size: int) -> tuple[dict[str, bytes], int, int, int]:
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


def _records(
    b: bytes | mmap.mmap, start: int, end: int
) -> Iterator[tuple[dict[str, bytes], int, int, int]]:
    """(header fields, op code, data start, data length) of each record in [start, end)."""
    pos = start
    while pos < end:
        hdr, ds, dl, pos = _record(b, pos, end)
        yield hdr, hdr["op"][0], ds, dl


def _connection(b: bytes | mmap.mmap, hdr: dict[str, bytes], ds: int, dl: int) -> _Conn:
    """A connection record: id and topic from its header, type and definition from its data."""
    d = _fields(b, ds, ds + dl)
    cid = _u32(hdr["conn"])
    return _Conn(
        cid,
        hdr["topic"].decode(),
        d["type"].decode(),
        d.get("message_definition", b"").decode(errors="replace"),
    )


def _u32(v: bytes) -> int:
    return int(_U32.unpack(v[:4])[0])


def _decompress(comp: str, data: bytes, size: int) -> bytes:
    if comp == "none":
        return data
    if comp == "bz2":
        return bz2.decompress(data)
    if comp == "lz4":
        import lz4.frame

        return bytes(lz4.frame.decompress(data))
    raise BagFormatError(f"unsupported chunk compression {comp!r}")


def scan_bag1(path: Path, topics: Iterable[str] | None, *, times_only: bool = False) -> RawLog:
    """Read an indexed ROS 1 bag: topic infos and raw messages of ``topics`` (None: all)."""
    with open(path, "rb") as fh:
        mm = mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ)
    try:
        return _scan(path, mm, len(mm), topics, times_only)
    finally:
        mm.close()


def _scan(
    path: Path, mm: mmap.mmap, size: int, topics: Iterable[str] | None, times_only: bool
) -> RawLog:
    if mm[: len(MAGIC)] != MAGIC:
        raise BagFormatError("not a ROS bag v2.0")
    hdr, _ds, _dl, _nxt = _record(mm, len(MAGIC), size)
    if hdr.get("op", b"\0")[:1] != bytes([OP_BAG_HEADER]):
        raise BagFormatError("first record is not the bag header")
    index_pos = struct.unpack("<Q", hdr["index_pos"][:8])[0]
    n_conn = _u32(hdr["conn_count"])
    n_chunk = _u32(hdr["chunk_count"])
    if index_pos == 0 or index_pos >= size:
        # Never closed (recorder killed) or cut short: recover what the chunks hold.
        return _walk_unindexed(path, mm, size, _nxt, topics)
    conns: dict[int, _Conn] = {}
    chunk_pos: list[int] = []
    for h, op, ds, dl in _records(mm, index_pos, size):
        if op == OP_CONNECTION:
            conn = _connection(mm, h, ds, dl)
            conns[conn.id] = conn
        elif op == OP_CHUNK_INFO:
            chunk_pos.append(struct.unpack("<Q", h["chunk_pos"][:8])[0])
    if len(conns) != n_conn or len(chunk_pos) != n_chunk:
        raise BagFormatError("index section does not match the bag header counts")
    want = None if topics is None else {norm_topic(t) for t in topics}
    builders: dict[int, TopicBuilder] = {}
    for cid, c in conns.items():
        name = norm_topic(c.topic)
        if want is None or name in want:
            builders[cid] = TopicBuilder(name, normalize_type_name(c.msgtype), "ros1", c.msgdef)
    times: dict[int, list[I64]] = {cid: [] for cid in conns}
    for cp in sorted(chunk_pos):
        h, ds, dl, pos = _record(mm, cp, size)
        if h["op"][0] != OP_CHUNK:
            raise BagFormatError(f"no chunk record at byte {cp}")
        # IndexData records follow the chunk: per connection, (time, offset) of its messages.
        entries: dict[int, NDArray[np.uint32]] = {}
        while pos < size:
            if pos + 4 > size:
                break
            ih, ids, idl, nxt = _record(mm, pos, size)
            if ih["op"][0] != OP_INDEX_DATA:
                break
            cid = _u32(ih["conn"])
            count = _u32(ih["count"])
            if idl != 12 * count:
                raise BagFormatError(f"index data at byte {pos} has the wrong size")
            entries[cid] = np.frombuffer(mm[ids : ids + idl], dtype="<u4").reshape(-1, 3)
            pos = nxt
        for cid, ent in entries.items():
            times[cid].append(ent[:, 0].astype(np.int64) * 1_000_000_000 + ent[:, 1])
        todo = {cid: e for cid, e in entries.items() if cid in builders}
        if not todo:
            continue
        if times_only:
            for cid, e in todo.items():
                z = np.zeros(len(e), np.int64)
                builders[cid].add(np.zeros(0, np.uint8), z, z, times[cid][-1])
            continue
        comp = h["compression"].decode()
        data = _decompress(comp, bytes(mm[ds : ds + dl]), _u32(h["size"]))
        buf = np.frombuffer(data, dtype=np.uint8)
        for cid, e in todo.items():
            rec = e[:, 2].astype(np.int64)
            hl = gather(buf, rec, 4).view("<u4").reshape(-1).astype(np.int64)
            dlen = gather(buf, rec + 4 + hl, 4).view("<u4").reshape(-1).astype(np.int64)
            builders[cid].add(buf, rec + 8 + hl, dlen, times[cid][-1])
    infos: dict[str, TopicInfo] = {}
    for cid, c in conns.items():
        name = norm_topic(c.topic)
        t = np.concatenate(times[cid]) if times[cid] else np.zeros(0, np.int64)
        old = infos.get(name)
        lo = [int(t.min())] if t.size else []
        hi = [int(t.max())] if t.size else []
        if old is not None and old.count:
            lo.append(old.start_ns)
            hi.append(old.end_ns)
        cnt = int(t.size) + (old.count if old else 0)
        infos[name] = TopicInfo(
            name, normalize_type_name(c.msgtype), cnt, min(lo) if lo else 0, max(hi) if hi else 0
        )
    raw: dict[str, RawTopic] = {}
    merged: dict[str, TopicBuilder] = {}
    for b in builders.values():
        top = b.build()
        m = merged.setdefault(top.name, TopicBuilder(top.name, top.msgtype, "ros1", top.msgdef))
        m.add(top.buf, top.offset, top.length, top.log_time)
    for name, m in merged.items():
        raw[name] = m.build()
    log = RawLog(path, list(infos.values()), raw)
    if not infos:
        log.notes.append("bag has no connections and no messages")
    return log


def _walk_unindexed(
    path: Path, mm: mmap.mmap, size: int, pos: int, topics: Iterable[str] | None
) -> RawLog:
    """Linear walk over the records of a bag without a usable index (slow path).

    Complete chunks are decoded record by record; the walk stops at the first record that
    is cut off, and the bytes after it are reported as lost.
    """
    want = None if topics is None else {norm_topic(t) for t in topics}
    conns: dict[int, _Conn] = {}
    payloads: dict[int, list[bytes]] = {}
    stamps: dict[int, list[int]] = {}
    lost = 0

    def records(b: bytes | mmap.mmap, start: int, end: int) -> None:
        for h, op, ds, dl in _records(b, start, end):
            if op == OP_CONNECTION:
                conn = _connection(b, h, ds, dl)
                conns[conn.id] = conn
            elif op == OP_MSG_DATA:
                cid = _u32(h["conn"])
                sec, nsec = struct.unpack("<II", h["time"][:8])
                payloads.setdefault(cid, []).append(bytes(b[ds : ds + dl]))
                stamps.setdefault(cid, []).append(sec * 1_000_000_000 + nsec)

    while pos < size:
        try:
            h, ds, dl, nxt = _record(mm, pos, size)
            if h["op"][0] == OP_CHUNK:
                data = _decompress(h["compression"].decode(), mm[ds : ds + dl], _u32(h["size"]))
                records(data, 0, len(data))
            elif h["op"][0] in (OP_CONNECTION, OP_MSG_DATA):
                records(mm, pos, nxt)
        except (BagFormatError, KeyError, OSError, ValueError, EOFError):
            lost = size - pos
            break
        pos = nxt
    builders: dict[str, TopicBuilder] = {}
    infos: dict[str, TopicInfo] = {}
    for cid, c in conns.items():
        name = norm_topic(c.topic)
        t = stamps.get(cid, [])
        old = infos.get(name)
        lo = [min(t)] if t else []
        hi = [max(t)] if t else []
        if old is not None and old.count:
            lo.append(old.start_ns)
            hi.append(old.end_ns)
        infos[name] = TopicInfo(
            name,
            normalize_type_name(c.msgtype),
            len(t) + (old.count if old else 0),
            min(lo) if lo else 0,
            max(hi) if hi else 0,
        )
        if want is None or name in want:
            b = builders.setdefault(
                name, TopicBuilder(name, normalize_type_name(c.msgtype), "ros1", c.msgdef)
            )
            b.add_payloads(payloads.get(cid, []), t)
    log = RawLog(
        path, list(infos.values()), {n: b.build() for n, b in builders.items()}, lost_bytes=lost
    )
    log.notes.append("bag has no index (not closed): recovered by a linear walk")
    return log
