"""Fast MCAP scanner: whole chunks in, per-topic payload buffers out, nothing trusted blindly.

The mcap library hands out one Python object per message; at a million messages that costs
seconds. This scanner walks only the top-level records (one step per chunk), decompresses
each chunk that holds a wanted channel once (zstd / lz4), checks it against its CRC, and
locates the wanted channels' messages from the chunk's MessageIndex records with numpy.

Nothing in the file is taken on faith (a damaged log must never give a silently wrong
number): the index is checked against the records it points at (each entry a Message record
of its channel with its log time, the records tiling the chunk with no message left out);
when they disagree the chunk is read by walking its records, with a warning. A chunk that
fails its CRC or cannot be decompressed is dropped, its messages counted per topic. A log
without summary/footer (recorder killed) is read record by record up to the cut, including
the decompressible prefix of a cut chunk (as ``mcap recover`` does), and says so. When the
summary's statistics count more messages on a wanted channel than were found, the difference
is counted as dropped. Chunk-level checks live in :mod:`uwval.io.mcap_chunk`.
"""

from __future__ import annotations

import contextlib
import mmap
import struct
import zlib
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from uwval.errors import LogReadError
from uwval.io.mcap_chunk import (
    MAGIC,
    OP_CHANNEL,
    OP_CHUNK,
    OP_CHUNK_INDEX,
    OP_DATA_END,
    OP_FOOTER,
    OP_MESSAGE,
    OP_MESSAGE_INDEX,
    OP_SCHEMA,
    OP_STATISTICS,
    REC,
    U16,
    U32,
    U64,
    Buffer,
    Tables,
    WalkResult,
    check_index,
    decompress,
    decompress_prefix,
    parse_chunk_header,
    walk_records,
)
from uwval.io.raw import (
    RawLog,
    TopicBuilder,
    TopicInfo,
    merge_infos,
    merge_topics,
    norm_topic,
    one_line,
    release_pages,
)

_MSG = struct.Struct("<HIQQ")


@dataclass
class _Summary:
    """What the summary section says: tables, per-channel message counts, chunk starts."""

    tables: Tables
    counts: dict[int, int] = field(default_factory=dict)
    chunk_starts: list[int] = field(default_factory=list)
    start: int = 0


def _read_summary(mm: Buffer, size: int, path: Path, warns: list[str]) -> _Summary | None:
    """The summary section, if the file has a valid one (footer, magic, CRC when present)."""
    if size < 8 + 29 + 8 or mm[size - 8 : size] != MAGIC:
        return None
    op, ln = REC.unpack_from(mm, size - 8 - 29)
    if op != OP_FOOTER or ln != 20:
        return None
    summary_start, _offs, crc = struct.unpack_from("<QQI", mm, size - 8 - 20)
    if summary_start == 0:
        return None
    if summary_start < 8 or summary_start > size - 8 - 29:
        warns.append(
            f"{path}: the footer's summary offset {summary_start} is outside the file; "
            "read without the summary"
        )
        return None
    if crc and zlib.crc32(mm[summary_start : size - 8 - 4]) != crc:
        warns.append(
            f"{path}: the summary section (byte {summary_start}) fails its CRC check; "
            "read without it"
        )
        return None
    out = _Summary(Tables(), start=summary_start)
    pos = summary_start
    end = size - 8 - 29
    try:
        while pos + 9 <= end:
            op, ln = REC.unpack_from(mm, pos)
            c = pos + 9
            if c + ln > end:
                raise struct.error("record runs past the footer")
            if op in (OP_SCHEMA, OP_CHANNEL):
                out.tables.record(op, mm, c, c + ln)
            elif op == OP_STATISTICS and ln >= 46:
                (n,) = U32.unpack_from(mm, c + 42)
                if n % 10 or c + 46 + n > c + ln:
                    raise struct.error("statistics channel counts do not fit")
                for k in range(c + 46, c + 46 + n, 10):
                    cid, cnt = struct.unpack_from("<HQ", mm, k)
                    out.counts[cid] = cnt
            elif op == OP_CHUNK_INDEX and ln >= 24:
                (start,) = U64.unpack_from(mm, c + 16)
                out.chunk_starts.append(start)
            pos = c + ln
    except (struct.error, UnicodeDecodeError) as exc:
        warns.append(
            f"{path}: summary record at byte {pos} is damaged ({one_line(exc)}); "
            "read without the summary"
        )
        return None
    out.chunk_starts.sort()
    return out


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
        if mm[:8] != MAGIC:
            raise LogReadError(f"{path}: not an MCAP file (bad magic bytes at offset 0)")
        return _Scanner(path, mm, size, topics, times_only).run()
    finally:
        # Payloads are compacted copies, so the map can go.
        with contextlib.suppress(BufferError):  # a numpy view may still reference it
            mm.close()


class _Scanner:
    """One pass over an MCAP file's top-level records."""

    def __init__(
        self,
        path: Path,
        mm: mmap.mmap,
        size: int,
        topics: Iterable[str] | None,
        times_only: bool,
    ) -> None:
        self.path, self.mm, self.size, self.times_only = path, mm, size, times_only
        self.want = None if topics is None else {norm_topic(t) for t in topics}
        self.warnings: list[str] = []
        self.summary = _read_summary(mm, size, path, self.warnings)
        self.tables = self.summary.tables if self.summary is not None else Tables()
        self.builders: dict[int, TopicBuilder | None] = {}
        self.lost = 0
        self.released = 0  # file map pages below this offset were dropped from RSS
        self.cut_detail = ""

    def builder(self, cid: int) -> TopicBuilder | None:
        """The builder of channel ``cid`` when its topic is wanted (``None`` otherwise)."""
        if cid in self.builders:
            return self.builders[cid]
        ch = self.tables.channels.get(cid)
        if ch is None:
            return None  # not known yet: decided when its Channel record is seen
        b: TopicBuilder | None = None
        if self.want is None or norm_topic(ch.topic) in self.want:
            typ, enc, text = self.tables.msgtype(ch)
            b = TopicBuilder(norm_topic(ch.topic), typ, enc, text)
            if self.summary is not None and not self.times_only:
                # the summary's count sizes one buffer (bounded: a lying count cannot
                # make it larger than a few times the file)
                b.reserve(self.summary.counts.get(cid, 0), 4 * self.size + (1 << 20))
        self.builders[cid] = b
        return b

    # ------------------------------------------------------------------ top level
    def run(self) -> RawLog:
        mm, size = self.mm, self.size
        pos = 8
        pending: tuple[int, int, int] | None = None  # (record start, content, length)
        indexes: dict[int, tuple[int, int]] = {}  # cid -> (start, length) of its entries
        end = self.summary.start if self.summary is not None else size
        while True:
            if pos >= end or pos + 9 > size:
                if self.summary is None:
                    self.lost = size - pos
                break
            op, ln = REC.unpack_from(mm, pos)
            c = pos + 9
            if op != OP_MESSAGE_INDEX and pending is not None:
                self.chunk(*pending, indexes)
                pending, indexes = None, {}
                self.released = release_pages(mm, self.released, pos)
            if op == OP_CHUNK and c + ln > size and self.summary is None:
                self.partial_chunk(pos, c)
                self.lost = size - pos
                break
            if op == 0 or op > 0x20 or c + ln > end:
                nxt = self.resync(pos)
                if nxt is None:
                    if self.summary is None:
                        self.lost = size - pos
                    else:
                        self.warnings.append(
                            f"{self.path}: no valid MCAP record at byte {pos} (opcode {op}); "
                            f"the {end - pos} bytes up to the summary could not be read"
                        )
                    break
                self.warnings.append(
                    f"{self.path}: no valid MCAP record at byte {pos} (opcode {op}); "
                    f"skipped {nxt - pos} damaged bytes to the next chunk at byte {nxt}"
                )
                pos = nxt
                continue
            if op == OP_CHUNK:
                pending = (pos, c, ln)
            elif op == OP_MESSAGE_INDEX and ln >= 6:
                (cid,) = U16.unpack_from(mm, c)
                (n,) = U32.unpack_from(mm, c + 2)
                indexes[cid] = (c + 6, n if 6 + n <= ln else -1)
            elif op in (OP_SCHEMA, OP_CHANNEL):
                self.record_table(op, mm, c, c + ln, pos)
            elif op == OP_MESSAGE and ln >= 22:
                self.message(c, ln)
            elif op in (OP_DATA_END, OP_FOOTER):
                break
            pos = c + ln
        if pending is not None:
            self.chunk(*pending, indexes)
        return self.result()

    def resync(self, pos: int) -> int | None:
        """The next chunk start after a damaged byte ``pos`` (from the summary), if any."""
        if self.summary is None:
            return None
        for s in self.summary.chunk_starts:
            if s > pos and s + 9 <= self.size and self.mm[s] == OP_CHUNK:
                return s
        return None

    def record_table(self, op: int, b: Buffer, c: int, end: int, where: int) -> bool:
        """Parse a Schema / Channel record; a damaged one is a warning, not a traceback."""
        try:
            self.tables.record(op, b, c, end)
        except (struct.error, ValueError) as exc:
            self.warnings.append(
                f"{self.path}: damaged {'Schema' if op == OP_SCHEMA else 'Channel'} record "
                f"at byte {where}: {one_line(exc)}"
            )
            return False
        return True

    def message(self, c: int, ln: int) -> None:
        """A top-level (unchunked) Message record."""
        cid, _seq, log_time, _pub = _MSG.unpack_from(self.mm, c)
        t = np.array([log_time], dtype=np.int64)
        self.tables.seen(cid, t)
        bld = self.builder(cid)
        if bld is not None:
            n = 0 if self.times_only else ln - 22
            data = np.frombuffer(bytes(self.mm[c + 22 : c + 22 + n]), dtype=np.uint8)
            bld.add(data, np.zeros(1, np.int64), np.array([n], np.int64), t, copy=False)

    # ------------------------------------------------------------------ chunks
    def _entries(self, indexes: dict[int, tuple[int, int]]) -> dict[int, np.ndarray] | None:
        """Per channel, the (log_time, offset) uint64 entries; ``None`` if malformed."""
        out: dict[int, np.ndarray] = {}
        for cid, (s, n) in indexes.items():
            if n < 0 or n % 16 or s + n > self.size:
                return None
            out[cid] = np.frombuffer(self.mm, dtype="<u8", count=n // 8, offset=s).reshape(-1, 2)
        return out

    def _drop(self, ents: dict[int, np.ndarray] | None, cause: str) -> str:
        """Count the indexed messages of wanted channels as dropped; describe them."""
        if ents is None:
            return "message count unknown (its index is damaged too)"
        parts = []
        for cid, e in ents.items():
            self.tables.seen(cid, e[:, 0].astype(np.int64))
            b = self.builder(cid)
            if b is not None and len(e):
                b.drop(cause, len(e))
                parts.append(f"{len(e)} on {b.name}")
        total = sum(len(e) for e in ents.values())
        return f"{total} message(s) dropped" + (f" ({', '.join(parts)})" if parts else "")

    def chunk(self, rec: int, c: int, ln: int, indexes: dict[int, tuple[int, int]]) -> None:
        """Read one complete Chunk record (and its MessageIndex records) into the builders."""
        ents = self._entries(indexes)
        where = f"{self.path}: MCAP chunk at byte {rec}"
        if self.summary is not None and ents:
            known = all(cid in self.tables.channels for cid in ents)
            if known and not any(self.builder(cid) is not None for cid in ents):
                for cid, e in ents.items():  # nothing wanted here: count from the index
                    self.tables.seen(cid, e[:, 0].astype(np.int64))
                return
        try:
            hdr = parse_chunk_header(self.mm, c, c + ln)
        except ValueError as exc:
            self.warnings.append(
                f"{where}: damaged chunk header ({exc}); {self._drop(ents, 'damaged_chunk')}"
            )
            return
        try:
            data = decompress(hdr.compression, self.mm, hdr.data_at, hdr.data_len, hdr.usize)
        except LogReadError as exc:
            self.warnings.append(f"{where}: {exc}; {self._drop(ents, 'damaged_chunk')}")
            return
        if len(data) != hdr.usize:
            self.warnings.append(
                f"{where}: decompresses to {len(data)} bytes, its header says {hdr.usize}; "
                + self._drop(ents, "damaged_chunk")
            )
            return
        if hdr.crc and zlib.crc32(data) != hdr.crc:
            self.warnings.append(
                f"{where} fails its CRC check; " + self._drop(ents, "crc_mismatch")
            )
            return
        buf = np.frombuffer(data, dtype=np.uint8)
        if ents:
            reason, gaps = check_index(buf, ents)
            if not reason:
                for op, a, b in gaps.tables:
                    self.record_table(op, buf, a, b, rec)
                self._from_index(buf, ents, gaps.record_lengths)
                return
            self.warnings.append(
                f"{where}: its MessageIndex disagrees with its records ({reason}); "
                "read the chunk by walking its records instead"
            )
        elif indexes:
            self.warnings.append(
                f"{where}: its MessageIndex records are malformed; "
                "read the chunk by walking its records instead"
            )
        walk = walk_records(data, 0, len(data))
        self._from_walk(buf, walk, rec)
        if walk.stop < len(data):
            self.warnings.append(
                f"{where}: record at byte {walk.stop} of the decompressed chunk is damaged "
                f"({walk.reason}); the chunk's last {len(data) - walk.stop} bytes were not read"
            )

    def _from_index(
        self, buf: np.ndarray, ents: dict[int, np.ndarray], rlens: dict[int, np.ndarray]
    ) -> None:
        """Add the wanted channels' messages located by a checked index."""
        for cid, e in ents.items():
            log_time = e[:, 0].astype(np.int64)
            self.tables.seen(cid, log_time)
            b = self.builder(cid)
            if b is None or not len(e):
                continue
            rec = e[:, 1].astype(np.int64)
            if self.times_only:
                z = np.zeros(len(rec), np.int64)
                b.add(buf[:0], z, z, log_time, copy=False)
                continue
            rl = rlens[cid]
            width = int(rl[0]) - 22
            if width > 0 and int(rl.min()) == int(rl.max()):
                # one payload length (a pose topic): one row gather, checked by check_index
                b.take_rows(buf, rec + 31, width, log_time)
            else:
                b.add(buf, rec + 31, rl - 22, log_time)

    def _from_walk(self, buf: np.ndarray, walk: WalkResult, rec: int) -> None:
        """Add messages found by walking a chunk's records (Schema/Channel records too)."""
        for op, c, end in walk.tables:
            self.record_table(op, buf, c, end, rec)
        for cid, (offs, lens, times) in walk.messages.items():
            t = np.asarray(times, dtype=np.int64)
            self.tables.seen(cid, t)
            b = self.builder(cid)
            if b is None:
                continue
            o = np.asarray(offs, dtype=np.int64)
            n = np.asarray(lens, dtype=np.int64)
            if self.times_only:
                o = n = np.zeros_like(t)
            b.add(buf, o, n, t)

    def partial_chunk(self, rec: int, c: int) -> None:
        """A chunk cut off by the end of the file: recover its decompressible prefix."""
        try:
            hdr = parse_chunk_header(self.mm, c, self.size, partial=True)
            data = decompress_prefix(hdr.compression, self.mm, hdr.data_at, self.size)
        except (ValueError, LogReadError):
            return
        walk = walk_records(data, 0, len(data))
        buf = np.frombuffer(data, dtype=np.uint8)
        self._from_walk(buf, walk, rec)
        n = sum(len(m[2]) for m in walk.messages.values())
        self.cut_detail = (
            f"the last chunk, at byte {rec}, is cut off; recovered {n} message(s) "
            "from its decompressible prefix"
        )

    # ------------------------------------------------------------------ result
    def result(self) -> RawLog:
        tables = self.tables
        if self.summary is not None:
            for cid, expected in sorted(self.summary.counts.items()):
                found = tables.counts.get(cid, 0)
                b = self.builder(cid)
                if found < expected:
                    name = b.name if b is not None else f"channel {cid}"
                    self.warnings.append(
                        f"{self.path}: the summary counts {expected} messages on {name}, "
                        f"{found} were found in the data section"
                    )
                    if b is not None:
                        b.drop("missing", expected - found)
        infos = []
        for cid, ch in sorted(tables.channels.items()):
            typ, _enc, _text = tables.msgtype(ch)
            t = tables.times.get(cid, [0, 0])
            infos.append(
                TopicInfo(norm_topic(ch.topic), typ, tables.counts.get(cid, 0), t[0], t[1])
            )
        built = [b.build() for b in self.builders.values() if b is not None]
        log = RawLog(self.path, merge_infos(infos), merge_topics(built), lost_bytes=self.lost)
        log.warnings = self.warnings
        log.cut_detail = self.cut_detail
        if self.summary is None:
            log.unclean = "no summary or footer: the writer did not finish"
        return log
