"""Fast ROS 1 bag (v2.0) scanner: per chunk, one decompress and numpy offset arithmetic.

A bag's index section lists connections and chunk positions; each chunk is followed by
IndexData records giving, per connection, every message's time and offset inside the
uncompressed chunk. From those offsets the payload positions are computed with two numpy
gathers (the record's header length, then its data length) instead of parsing every
message record in Python. The wanted connections' entries are checked against the records
they point at (op, connection, time, bounds); the other connections are counted from the
index. Files this scanner cannot follow (unindexed, damaged) are handed
to rosbags' reader by :mod:`uwval.io.containers`, which reports the cause.
"""

from __future__ import annotations

import bz2
import mmap
import os
import struct
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from uwval.errors import LogReadError
from uwval.io.fastdecode import gather
from uwval.io.raw import (
    Buffer,
    RawLog,
    TopicBuilder,
    TopicInfo,
    merge_infos,
    merge_topics,
    norm_topic,
    unaligned,
)
from uwval.io.ros import normalize_type_name

try:  # the optional C check of IndexData entries (uwval/io/_bag1index.c)
    from uwval.io import _bag1index
except ImportError:  # pragma: no cover - installs without a C compiler: the numpy check
    _bag1index = None  # type: ignore[assignment]

#: Whether the wanted connections' entries are checked (and located) by the C accelerator:
#: built and ``UWVAL_NO_ACCELERATOR`` not set; else :func:`_index_ok` alone (same result).
USE_LOCATE = _bag1index is not None and not os.environ.get("UWVAL_NO_ACCELERATOR")

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


class BagFormatError(LogReadError):
    """The bag does not have the structure this scanner follows (use the fallback)."""


@dataclass
class _Conn:
    id: int
    topic: str
    msgtype: str
    msgdef: str


def _fields(b: Buffer, pos: int, end: int) -> dict[str, bytes]:
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


def _record(b: Buffer, pos: int, size: int) -> tuple[dict[str, bytes], int, int, int]:
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


def _records(b: Buffer, start: int, end: int) -> Iterator[tuple[dict[str, bytes], int, int, int]]:
    """(header fields, op code, data start, data length) of each record in [start, end)."""
    pos = start
    while pos < end:
        hdr, ds, dl, pos = _record(b, pos, end)
        yield hdr, hdr["op"][0], ds, dl


def _connection(b: Buffer, hdr: dict[str, bytes], ds: int, dl: int) -> _Conn:
    """A connection record: id and topic from its header, type and definition from its data.

    Text that is not UTF-8 is damage (rosbags refuses it too): :class:`UnicodeDecodeError`.
    """
    d = _fields(b, ds, ds + dl)
    cid = _u32(hdr["conn"])
    d["md5sum"].decode()  # required, as rosbags requires it (KeyError / decode error: damage)
    return _Conn(
        cid,
        hdr["topic"].decode(),
        d["type"].decode(),
        d["message_definition"].decode(),
    )


def _u32(v: bytes) -> int:
    return int(_U32.unpack(v[:4])[0])


def _decompress(comp: str, data: bytes, size: int) -> bytes:
    """A chunk's records; :class:`BagFormatError` (one line) when they cannot be had."""
    try:
        if comp == "none":
            out = data
        elif comp == "bz2":
            out = bz2.decompress(data)
        elif comp == "lz4":
            import lz4.frame

            out = bytes(lz4.frame.decompress(data))
        else:
            raise BagFormatError(f"unsupported chunk compression {comp!r}")
    except BagFormatError:
        raise
    except Exception as exc:  # bz2: OSError/ValueError; lz4: RuntimeError
        raise BagFormatError(
            f"{comp} data cannot be decompressed ({type(exc).__name__}: "
            + " ".join(str(exc).split())
            + ")"
        ) from exc
    if len(out) != size:
        raise BagFormatError(f"chunk decompresses to {len(out)} bytes, its header says {size}")
    return out


def scan_bag1(path: Path, topics: Iterable[str] | None, *, times_only: bool = False) -> RawLog:
    """Read an indexed ROS 1 bag: topic infos and raw messages of ``topics`` (None: all)."""
    with open(path, "rb") as fh:
        mm = mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ)
    try:
        return _scan(path, mm, len(mm), topics, times_only)
    finally:
        mm.close()


def _index_section(
    mm: mmap.mmap, index_pos: int, size: int
) -> tuple[dict[int, _Conn], dict[int, dict[int, int]]]:
    """Connections, and per chunk position its message count per connection (ChunkInfo)."""
    conns: dict[int, _Conn] = {}
    chunks: dict[int, dict[int, int]] = {}
    for h, op, ds, dl in _records(mm, index_pos, size):
        if op == OP_CONNECTION:
            conn = _connection(mm, h, ds, dl)
            conns[conn.id] = conn
        elif op == OP_CHUNK_INFO:
            cp = struct.unpack("<Q", h["chunk_pos"][:8])[0]
            if dl % 8 or _u32(h["count"]) * 8 != dl or not {"start_time", "end_time"} <= set(h):
                raise BagFormatError(f"chunk info at byte {ds} is malformed")
            pairs = np.frombuffer(mm[ds : ds + dl], dtype="<u4").reshape(-1, 2)
            chunks[cp] = {int(a): int(b) for a, b in pairs}
    return conns, chunks


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
        return _walk_unindexed(path, mm, size, _nxt, topics, "no index: the writer did not finish")
    try:
        conns, chunk_info = _index_section(mm, index_pos, size)
        if len(conns) != n_conn or len(chunk_info) != n_chunk:
            raise BagFormatError("index section does not match the bag header counts")
    except (BagFormatError, KeyError, ValueError, struct.error) as exc:
        log = _walk_unindexed(path, mm, size, _nxt, topics, "")
        log.warnings.insert(
            0,
            f"{path}: the index section at byte {index_pos} is damaged ({_why(exc)}); "
            "read by a linear walk over the records",
        )
        return log
    want = None if topics is None else {norm_topic(t) for t in topics}
    builders: dict[int, TopicBuilder] = {}
    for cid, c in conns.items():
        name = norm_topic(c.topic)
        if want is None or name in want:
            builders[cid] = TopicBuilder(name, normalize_type_name(c.msgtype), "ros1", c.msgdef)
    times: dict[int, list[I64]] = {cid: [] for cid in conns}
    warns: list[str] = []
    for cp in sorted(chunk_info):
        expected = chunk_info[cp]
        try:
            _chunk(mm, size, cp, expected, builders, times, times_only, warns, path)
        except (BagFormatError, KeyError, ValueError, struct.error) as exc:
            lost = {c: n for c, n in expected.items() if c in builders}
            for cid, n in lost.items():
                builders[cid].drop("damaged_chunk", n)
                times.setdefault(cid, [])
            warns.append(
                f"{path}: ROS 1 chunk at byte {cp} is damaged ({_why(exc)}); "
                + _lost_text(lost, builders, expected)
            )
    infos = [
        TopicInfo(
            norm_topic(c.topic),
            normalize_type_name(c.msgtype),
            int(sum(x.size for x in times.get(cid, []))),
            int(min(int(x.min()) for x in times[cid] if x.size)) if _any(times, cid) else 0,
            int(max(int(x.max()) for x in times[cid] if x.size)) if _any(times, cid) else 0,
        )
        for cid, c in conns.items()
    ]
    log = RawLog(path, merge_infos(infos), merge_topics(b.build() for b in builders.values()))
    log.warnings = warns
    if not infos:
        log.notes.append("bag has no connections and no messages")
    return log


def _any(times: dict[int, list[I64]], cid: int) -> bool:
    return any(x.size for x in times.get(cid, []))


def _why(exc: BaseException) -> str:
    return " ".join(str(exc).split()) or type(exc).__name__


def _lost_text(
    lost: dict[int, int], builders: dict[int, TopicBuilder], expected: dict[int, int]
) -> str:
    total = sum(expected.values())
    parts = ", ".join(f"{n} on {builders[c].name}" for c, n in lost.items() if n)
    return f"its {total} message(s) were dropped" + (f" ({parts})" if parts else "")


def _chunk(
    mm: mmap.mmap,
    size: int,
    cp: int,
    expected: dict[int, int],
    builders: dict[int, TopicBuilder],
    times: dict[int, list[I64]],
    times_only: bool,
    warns: list[str],
    path: Path,
) -> None:
    """One chunk and its IndexData records into the builders (checked against each other)."""
    h, ds, dl, pos = _record(mm, cp, size)
    if h["op"][0] != OP_CHUNK:
        raise BagFormatError(f"no chunk record at byte {cp}")
    # IndexData records follow the chunk: per connection, (time, offset) of its messages.
    found_ix: dict[int, NDArray[np.uint32]] = {}
    entries: dict[int, NDArray[np.uint32]] | None = found_ix
    try:
        while pos + 4 <= size and len(found_ix) < len(expected):
            ih, ids, idl, nxt = _record(mm, pos, size)
            if ih["op"][0] != OP_INDEX_DATA:
                break
            cid = _u32(ih["conn"])
            count = _u32(ih["count"])
            if idl != 12 * count:
                raise BagFormatError(f"index data at byte {pos} has the wrong size")
            found_ix[cid] = np.frombuffer(mm[ids : ids + idl], dtype="<u4").reshape(-1, 3)
            pos = nxt
        if {c: len(e) for c, e in found_ix.items()} != expected:
            raise BagFormatError("its IndexData records disagree with the chunk info")
    except (BagFormatError, KeyError, ValueError, struct.error) as exc:
        warns.append(
            f"{path}: index data after the ROS 1 chunk at byte {cp} is damaged ({_why(exc)}); "
            "read the chunk by walking its records"
        )
        entries = None
    wanted = [c for c in expected if c in builders]
    if entries is not None and (times_only or not wanted):
        for cid, e in entries.items():
            t = e[:, 0].astype(np.int64) * 1_000_000_000 + e[:, 1]
            times.setdefault(cid, []).append(t)
            if cid in builders:
                z = np.zeros(len(e), np.int64)
                builders[cid].add(np.zeros(0, np.uint8), z, z, t, copy=False)
        return
    data = _decompress(h["compression"].decode(), bytes(mm[ds : ds + dl]), _u32(h["size"]))
    buf = np.frombuffer(data, dtype=np.uint8)
    if entries is not None:
        # The wanted connections' entries are checked against their records; the others
        # are only counted (from the index, as chunks holding no wanted connection are).
        located = {c: _locate(buf, c, e) for c, e in entries.items() if c in builders}
        bad = next(
            (
                c
                for c, e in entries.items()
                if c in builders and located[c] is None and not _index_ok(buf, c, e)
            ),
            None,
        )
        if bad is None:
            u32 = unaligned(buf, "<u4")
            for cid, e in entries.items():
                t = e[:, 0].astype(np.int64) * 1_000_000_000 + e[:, 1]
                times.setdefault(cid, []).append(t)
                if cid in builders:
                    loc = located[cid]
                    if loc is not None:  # the C check gave each record's data place
                        data_at, dlen = loc[:, 0], loc[:, 1]
                    else:
                        rec = e[:, 2].astype(np.int64)
                        hl = u32[rec].astype(np.int64)
                        data_at = rec + 8 + hl
                        dlen = u32[rec + 4 + hl].astype(np.int64)
                    width = int(dlen[0])
                    if width > 0 and int(dlen.min()) == int(dlen.max()):
                        # one payload length (a pose topic), bounds checked by the check
                        builders[cid].take_rows(buf, data_at, width, t)
                    else:
                        builders[cid].add(buf, data_at, dlen, t)
            return
        warns.append(
            f"{path}: the index of the ROS 1 chunk at byte {cp} disagrees with its records "
            f"(connection {bad}); read the chunk by walking its records"
        )
    found: dict[int, tuple[list[int], list[int], list[int]]] = {}
    q = 0
    stop = ""
    while q < len(data):
        try:
            rh, rds, rdl, nq = _record(data, q, len(data))
            if rh["op"][0] == OP_MSG_DATA:
                cid = _u32(rh["conn"])
                sec, nsec = struct.unpack("<II", rh["time"][:8])
                m = found.setdefault(cid, ([], [], []))
                m[0].append(rds)
                m[1].append(rdl)
                m[2].append(sec * 1_000_000_000 + nsec)
        except (BagFormatError, KeyError, ValueError, struct.error, IndexError) as exc:
            stop = f"record at byte {q} of the chunk is damaged ({_why(exc)})"
            break
        q = nq
    for cid, (o, ln, stamps) in found.items():
        tt = np.asarray(stamps, dtype=np.int64)
        times.setdefault(cid, []).append(tt)
        if cid in builders:
            builders[cid].add(buf, np.asarray(o, np.int64), np.asarray(ln, np.int64), tt)
    lost = {c: n - len(found.get(c, ([], [], []))[2]) for c, n in expected.items()}
    lost = {c: n for c, n in lost.items() if n > 0}
    for cid, n in lost.items():
        if cid in builders:
            builders[cid].drop("damaged_record", n)
    if stop or lost:
        warns.append(
            f"{path}: ROS 1 chunk at byte {cp}: {stop or 'records missing'}; "
            f"{sum(lost.values())} of its {sum(expected.values())} message(s) could not be read"
            + (
                " ("
                + ", ".join(f"{n} on {builders[c].name}" for c, n in lost.items() if c in builders)
                + ")"
                if any(c in builders for c in lost)
                else ""
            )
        )


def _locate(buf: NDArray[np.uint8], cid: int, e: NDArray[np.uint32]) -> NDArray[np.int64] | None:
    """(data start, data length) of each indexed record of ``cid``, checked by the C
    accelerator as :func:`_index_ok` checks them (narrower: a header it does not take is
    left to :func:`_index_ok`); None without it, or when it does not confirm the entries."""
    if not USE_LOCATE or not len(e):
        return None
    out = np.empty((len(e), 2), dtype=np.int64)
    return out if _bag1index.locate(buf, cid, np.ascontiguousarray(e), out) else None


def _index_ok(buf: NDArray[np.uint8], cid: int, e: NDArray[np.uint32]) -> bool:
    """Whether every IndexData entry of ``cid`` points at a MessageData record of ``cid``
    with the entry's time, lying inside the chunk (vectorised: headers of one layout are
    compared with the first one's bytes, the time field with the index's times)."""
    n = len(e)
    if n == 0:
        return True
    size = buf.shape[0]
    rec = e[:, 2].astype(np.int64)
    if int(rec.max()) + 8 > size:
        return False
    u32 = unaligned(buf, "<u4")
    hl = u32[rec].astype(np.int64)
    if int(hl.min()) != int(hl.max()) or int((rec + 8 + hl).max()) > size:
        return _index_ok_slow(buf, cid, e)
    h0 = int(hl[0])
    try:
        fields = _fields(buf, int(rec[0]) + 4, int(rec[0]) + 4 + h0)
    except (BagFormatError, UnicodeDecodeError):
        return False
    if fields.get("op", b"")[:1] != bytes([OP_MSG_DATA]) or fields.get("conn", b"")[
        :4
    ] != struct.pack("<I", cid):
        return False
    heads = gather(buf, rec + 4, h0)
    tpos = bytes(heads[0]).find(b"time=")
    if tpos < 0 or tpos + 13 > h0:
        return False
    mask = np.ones(h0, dtype=bool)
    mask[tpos + 5 : tpos + 13] = False
    if not bool((heads[:, mask] == heads[0, mask]).all()):
        return _index_ok_slow(buf, cid, e)
    stamp = np.ascontiguousarray(heads[:, tpos + 5 : tpos + 13]).view("<u4").reshape(-1, 2)
    if not np.array_equal(stamp, e[:, :2]):
        return False
    dlen = u32[rec + 4 + hl].astype(np.int64)
    return bool(int((rec + 8 + hl + dlen).max()) <= size)


def _index_ok_slow(buf: NDArray[np.uint8], cid: int, e: NDArray[np.uint32]) -> bool:
    """Record-by-record form of :func:`_index_ok` (headers of varying layout)."""
    for sec, nsec, off in e:
        try:
            h, _ds, _dl, _nxt = _record(buf, int(off), buf.shape[0])
        except (BagFormatError, UnicodeDecodeError, struct.error):
            return False
        if h.get("op", b"")[:1] != bytes([OP_MSG_DATA]) or _u32(h.get("conn", b"")) != cid:
            return False
        if h.get("time", b"")[:8] != struct.pack("<II", int(sec), int(nsec)):
            return False
    return True


def _walk_unindexed(
    path: Path, mm: mmap.mmap, size: int, pos: int, topics: Iterable[str] | None, unclean: str
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
    stop = ""

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
        except (BagFormatError, KeyError, OSError, ValueError, EOFError, struct.error) as exc:
            lost = size - pos
            stop = f"record at byte {pos}: {_why(exc)}"
            break
        pos = nxt
    builders: dict[str, TopicBuilder] = {}
    infos: list[TopicInfo] = []
    for cid, c in conns.items():
        name = norm_topic(c.topic)
        t = stamps.get(cid, [])
        infos.append(
            TopicInfo(
                name, normalize_type_name(c.msgtype), len(t), min(t) if t else 0, max(t) if t else 0
            )
        )
        if want is None or name in want:
            b = builders.setdefault(
                name, TopicBuilder(name, normalize_type_name(c.msgtype), "ros1", c.msgdef)
            )
            b.add_payloads(payloads.get(cid, []), t)
    log = RawLog(
        path, merge_infos(infos), {n: b.build() for n, b in builders.items()}, lost_bytes=lost
    )
    log.unclean = unclean
    if lost and not unclean:
        log.warnings.append(
            f"{path}: the linear walk stopped at a damaged {stop}; the {lost} bytes after it "
            "could not be read"
        )
        log.lost_bytes = 0
    return log
