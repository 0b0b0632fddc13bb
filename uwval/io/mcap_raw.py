"""Fast MCAP scanner: whole chunks in, per-topic payload buffers out.

The mcap library hands out one Python object per message; at a million messages that costs
seconds. This scanner walks only the top-level records (one step per chunk), decompresses
each chunk once (zstd / lz4), and locates the wanted channels' messages from the chunk's
MessageIndex records with numpy. Without a summary (a recorder killed before ``finish()``)
it walks the records inside each chunk instead, and stops at the first incomplete record,
reporting the bytes lost. The mcap library stays the correctness reference in the tests.
"""

from __future__ import annotations

import contextlib
import mmap
import struct
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from uwval.errors import LogReadError
from uwval.io.raw import RawLog, RawTopic, TopicBuilder, TopicInfo, norm_topic
from uwval.io.ros import normalize_type_name

MAGIC = b"\x89MCAP0\r\n"
OP_HEADER, OP_FOOTER, OP_SCHEMA, OP_CHANNEL, OP_MESSAGE, OP_CHUNK = 1, 2, 3, 4, 5, 6
OP_MESSAGE_INDEX, OP_STATISTICS, OP_DATA_END = 7, 11, 15

_REC = struct.Struct("<BQ")
_U16 = struct.Struct("<H")
_U32 = struct.Struct("<I")
_U64 = struct.Struct("<Q")
_MSG = struct.Struct("<HIQQ")
_CHUNK = struct.Struct("<QQQI")

U8 = NDArray[np.uint8]
I64 = NDArray[np.int64]


def _string(b: bytes | memoryview | mmap.mmap, pos: int) -> tuple[str, int]:
    (n,) = _U32.unpack_from(b, pos)
    return bytes(b[pos + 4 : pos + 4 + n]).decode("utf-8", errors="replace"), pos + 4 + n


@dataclass
class _Channel:
    id: int
    topic: str
    encoding: str
    schema_id: int


@dataclass
class _Tables:
    schemas: dict[int, tuple[str, str, str]] = field(default_factory=dict)  # name, enc, text
    channels: dict[int, _Channel] = field(default_factory=dict)
    counts: dict[int, int] = field(default_factory=dict)
    times: dict[int, list[int]] = field(default_factory=dict)  # cid -> [min, max]

    def record(self, op: int, b: bytes | memoryview | mmap.mmap, pos: int) -> None:
        """Parse a Schema or Channel record whose content starts at ``pos``."""
        if op == OP_SCHEMA:
            (sid,) = _U16.unpack_from(b, pos)
            name, p = _string(b, pos + 2)
            enc, p = _string(b, p)
            text, _ = _string(b, p)
            self.schemas[sid] = (name, enc, text)
        elif op == OP_CHANNEL:
            cid, sid = struct.unpack_from("<HH", b, pos)
            topic, p = _string(b, pos + 4)
            enc, _ = _string(b, p)
            self.channels[cid] = _Channel(cid, topic, enc, sid)

    def msgtype(self, ch: _Channel) -> tuple[str, str, str]:
        """(normalised type, 'cdr'|'ros1'|other encoding, definition text) of a channel."""
        name, _senc, text = self.schemas.get(ch.schema_id, ("", "", ""))
        enc = {"cdr": "cdr", "ros1": "ros1"}.get(ch.encoding, ch.encoding)
        return normalize_type_name(name) if name else "", enc, text

    def seen(self, cid: int, times: I64) -> None:
        if times.size == 0:
            return
        self.counts[cid] = self.counts.get(cid, 0) + int(times.size)
        lo, hi = int(times.min()), int(times.max())
        cur = self.times.setdefault(cid, [lo, hi])
        cur[0], cur[1] = min(cur[0], lo), max(cur[1], hi)


def _decompress(path: Path, compression: str, data: memoryview, size: int) -> bytes:
    if compression == "":
        return bytes(data)
    if compression == "zstd":
        import zstandard

        return zstandard.ZstdDecompressor().decompress(data, max_output_size=size)
    if compression == "lz4":
        import lz4.frame

        return bytes(lz4.frame.decompress(data))
    raise LogReadError(f"{path}: unsupported MCAP chunk compression {compression!r}")


def _read_summary(mm: mmap.mmap | bytes, size: int) -> _Tables | None:
    """Schemas, channels and statistics from the summary section, if the file has one."""
    if size < 8 + 29 + 8 or mm[size - 8 : size] != MAGIC:
        return None
    op, ln = _REC.unpack_from(mm, size - 8 - 29)
    if op != OP_FOOTER or ln != 20:
        return None
    summary_start, _ = struct.unpack_from("<QQ", mm, size - 8 - 20)
    if summary_start == 0 or summary_start >= size:
        return None
    tables = _Tables()
    pos = summary_start
    end = size - 8 - 29
    while pos + 9 <= end:
        op, ln = _REC.unpack_from(mm, pos)
        c = pos + 9
        if op in (OP_SCHEMA, OP_CHANNEL):
            tables.record(op, mm, c)
        pos = c + ln
    # Counts and spans are taken from the scan itself (exact even for odd summaries).
    return tables


def scan_mcap(path: Path, topics: Iterable[str] | None, *, times_only: bool = False) -> RawLog:
    """Read an MCAP file: all topics' infos, and the raw messages of ``topics``.

    ``topics`` are compared after :func:`norm_topic`; ``None`` means every topic.
    ``times_only`` keeps log times but no payloads (for ``inspect``).
    """
    size = path.stat().st_size
    if size == 0:
        raise LogReadError(f"{path}: file is empty (0 bytes)")
    with open(path, "rb") as fh:
        mm = mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ)
    try:
        return _scan(path, mm, size, topics, times_only)
    finally:
        # Payload buffers are copies (chunks) or slices copied by np.concatenate/frombuffer
        # of bytes, so the map can go.
        with contextlib.suppress(BufferError):  # a numpy view may still reference it
            mm.close()


def _scan(
    path: Path, mm: mmap.mmap, size: int, topics: Iterable[str] | None, times_only: bool
) -> RawLog:
    if mm[:8] != MAGIC:
        raise LogReadError(f"{path}: not an MCAP file (bad magic bytes at offset 0)")
    want = None if topics is None else {norm_topic(t) for t in topics}
    summary = _read_summary(mm, size)
    tables = summary if summary is not None else _Tables()
    builders: dict[int, TopicBuilder] = {}

    def builder(cid: int) -> TopicBuilder | None:
        if cid in builders:
            return builders[cid]
        ch = tables.channels.get(cid)
        if ch is None or (want is not None and norm_topic(ch.topic) not in want):
            return None
        typ, enc, text = tables.msgtype(ch)
        b = builders[cid] = TopicBuilder(norm_topic(ch.topic), typ, enc, text)
        return b

    pos = 8
    lost = 0
    pending: tuple[int, int] | None = None  # (content start, length) of the last chunk
    indexes: dict[int, tuple[int, int]] = {}  # cid -> (start, length) of its index entries
    mv = memoryview(mm)
    try:
        while True:
            if pos + 9 > size:
                lost = size - pos
                break
            op, ln = _REC.unpack_from(mm, pos)
            c = pos + 9
            if c + ln > size or op == 0 or op > 0x20:
                lost = size - pos
                break
            if op != OP_MESSAGE_INDEX and pending is not None:
                lost += _chunk(
                    path, mv, pending, indexes, tables, builder, summary is not None, times_only
                )
                pending, indexes = None, {}
            if op == OP_CHUNK:
                pending = (c, ln)
            elif op == OP_MESSAGE_INDEX:
                (cid,) = _U16.unpack_from(mm, c)
                (n,) = _U32.unpack_from(mm, c + 2)
                indexes[cid] = (c + 6, n)
            elif op in (OP_SCHEMA, OP_CHANNEL):
                tables.record(op, mm, c)
            elif op == OP_MESSAGE:
                cid, _seq, log_time, _pub = _MSG.unpack_from(mm, c)
                tbl_times = np.array([log_time], dtype=np.int64)
                tables.seen(cid, tbl_times)
                bld = builder(cid)
                if bld is not None:
                    data = np.frombuffer(bytes(mv[c + 22 : c + ln]), dtype=np.uint8)
                    bld.add(data, np.zeros(1, np.int64), np.array([ln - 22]), tbl_times)
            elif op in (OP_DATA_END, OP_FOOTER):
                break
            pos = c + ln
        if pending is not None:
            lost += _chunk(
                path, mv, pending, indexes, tables, builder, summary is not None, times_only
            )
    finally:
        with contextlib.suppress(BufferError):
            mv.release()
    infos = []
    for cid, ch in sorted(tables.channels.items()):
        typ, _enc, _text = tables.msgtype(ch)
        t = tables.times.get(cid, [0, 0])
        infos.append(TopicInfo(norm_topic(ch.topic), typ, tables.counts.get(cid, 0), t[0], t[1]))
    raw: dict[str, RawTopic] = {}
    for b in builders.values():
        top = b.build()
        if top.name in raw:  # several channels on one topic
            merged = TopicBuilder(top.name, top.msgtype, top.encoding, top.msgdef)
            for part in (raw[top.name], top):
                merged.add(part.buf, part.offset, part.length, part.log_time)
            top = merged.build()
        raw[top.name] = top
    return RawLog(path, _merge_infos(infos), raw, lost_bytes=lost)


def _merge_infos(infos: list[TopicInfo]) -> list[TopicInfo]:
    out: dict[str, TopicInfo] = {}
    for i in infos:
        if i.name in out:
            o = out[i.name]
            starts = [x.start_ns for x in (o, i) if x.count]
            out[i.name] = TopicInfo(
                i.name,
                o.type or i.type,
                o.count + i.count,
                min(starts) if starts else 0,
                max(o.end_ns, i.end_ns),
            )
        else:
            out[i.name] = i
    return list(out.values())


def _index_fits(mv: memoryview, wanted: dict[int, tuple[int, int]], size: int) -> bool:
    """Whether every MessageIndex entry points at a Message record inside the chunk."""
    for s, n in wanted.values():
        if n % 16:
            return False
        if n:
            rec = np.frombuffer(mv[s : s + n], dtype="<u8").reshape(-1, 2)[:, 1]
            if int(rec.max()) + 31 > size:
                return False
    return True


def _chunk(
    path: Path,
    mv: memoryview,
    chunk: tuple[int, int],
    indexes: dict[int, tuple[int, int]],
    tables: _Tables,
    builder: object,
    trusted_index: bool,
    times_only: bool,
) -> int:
    """Decode one chunk into the builders; returns bytes lost (0, or the chunk if corrupt)."""
    c, ln = chunk
    _start, _end, usize, _crc = _CHUNK.unpack_from(mv, c)
    comp, p = _string(mv, c + 28)
    (rlen,) = _U64.unpack_from(mv, p)
    get = builder  # Callable[[int], TopicBuilder | None]
    if trusted_index and indexes:
        wanted = {cid: ix for cid, ix in indexes.items() if get(cid) is not None}  # type: ignore[operator]
        for cid, (s, n) in indexes.items():
            if n:
                ent = np.frombuffer(mv[s : s + n], dtype="<u8").reshape(-1, 2)
                tables.seen(cid, ent[:, 0].astype(np.int64))
        if not wanted:
            return 0
    try:
        data = _decompress(path, comp, mv[p + 8 : p + 8 + rlen], usize)
    except LogReadError:
        raise
    except Exception:
        return ln + 9  # a damaged chunk: its messages are lost, the others still read
    buf = np.frombuffer(data, dtype=np.uint8)
    if trusted_index and indexes and _index_fits(mv, wanted, buf.shape[0]):
        for cid, (s, n) in wanted.items():
            ent = np.frombuffer(mv[s : s + n], dtype="<u8").reshape(-1, 2)
            rec = ent[:, 1].astype(np.int64)
            log_time = ent[:, 0].astype(np.int64)
            if times_only:
                get(cid).add(
                    buf[:0],
                    np.zeros(len(rec), np.int64),  # type: ignore[operator]
                    np.zeros(len(rec), np.int64),
                    log_time,
                )
                continue
            rlen_all = np.empty(len(rec), dtype=np.int64)
            from uwval.io.fastdecode import gather

            rlen_all[:] = gather(buf, rec + 1, 8).view("<u8").reshape(-1)
            if (rlen_all < 22).any() or (rec + 9 + rlen_all > buf.shape[0]).any():
                break  # a damaged record length: walk the chunk instead (bounds-checked)
            get(cid).add(buf, rec + 31, rlen_all - 22, log_time)  # type: ignore[operator]
        else:
            return 0
        for cid in wanted:
            get(cid).drop_last_from(buf)  # type: ignore[operator]
    # No usable index: walk the chunk's records.
    offs: dict[int, list[int]] = {}
    lens: dict[int, list[int]] = {}
    times: dict[int, list[int]] = {}
    q = 0
    end = len(data)
    while q + 9 <= end:
        op, rl = _REC.unpack_from(data, q)
        cc = q + 9
        if cc + rl > end:
            break
        if op == OP_MESSAGE and rl >= 22:
            cid, _seq, lt, _pub = _MSG.unpack_from(data, cc)
            offs.setdefault(cid, []).append(cc + 22)
            lens.setdefault(cid, []).append(rl - 22)
            times.setdefault(cid, []).append(lt)
        elif op in (OP_SCHEMA, OP_CHANNEL):
            tables.record(op, data, cc)
        q = cc + rl
    for cid, o in offs.items():
        lt_arr = np.asarray(times[cid], dtype=np.int64)
        if not (trusted_index and indexes):  # else already counted from the index
            tables.seen(cid, lt_arr)
        bld = get(cid)  # type: ignore[operator]
        if bld is not None:
            bld.add(
                buf, np.asarray(o, dtype=np.int64), np.asarray(lens[cid], dtype=np.int64), lt_arr
            )
    return 0
