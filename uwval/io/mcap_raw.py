"""The MCAP reader: whole chunks in, per-topic payload buffers out, nothing trusted blindly.

It walks the top-level records (a step per chunk and index, not per message: mcap's reader
makes an object per message), reads the summary with mcap's record parsers, decompresses
runs of chunks on threads while the run before is read, and finds the wanted messages from
the MessageIndex records with numpy. What it checks, and warns about by byte offset, is in
docs/formats-mcap.md (chunk-level checks: :mod:`uwval.io.mcap_chunk`).
"""

from __future__ import annotations

import contextlib
import io
import mmap
import struct
from collections import deque
from collections.abc import Iterable
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np
import zstandard
from mcap.data_stream import ReadDataStream, RecordBuilder
from mcap.opcode import Opcode
from mcap.records import Channel, ChunkIndex, Schema, Statistics
from mcap.stream_reader import StreamReader
from numpy.typing import NDArray

from uwval.errors import LogReadError
from uwval.io.crc import crc32
from uwval.io.mcap_chunk import (
    REC,
    ChunkHeader,
    check_index,
    decompress_prefix,
    inflate_into,
    parse_chunk_header,
    walk_records,
)
from uwval.io.raw import (
    I64,
    U8,
    RawLog,
    TopicBuilder,
    TopicInfo,
    merge_infos,
    merge_topics,
    norm_topic,
    one_line,
)
from uwval.io.ros import normalize_type_name

MAGIC = b"\x89MCAP0\r\n"
#: bytes of records decompressed into one buffer and checked together (numpy's per-call
#: cost, not the bytes, dominates small chunks). 8 MB against 4 MB on the image log, whole
#: command, loaded machine: CPU 0.39-0.47 vs 0.43-0.49 s, peak RSS 90 vs 78 MB (evo's 113)
BATCH_BYTES = 8 << 20
THREADS = 2
_U16, _U32, _INDEX = struct.Struct("<H"), struct.Struct("<I"), struct.Struct("<HI")
#: a chunk: (record start, header or what is wrong with it, {channel: (index entries at,
#: their bytes)} from its MessageIndex records)
_Index = dict[int, tuple[int, int]]
_Chunk = tuple[int, "ChunkHeader | str", _Index]
#: a chunk's MessageIndex entries per channel: (log time, record offset) uint64 rows
_Ents = dict[int, NDArray[np.uint64]]
_Job = Future[tuple[U8, list[tuple[str, str]]]]


def scan_mcap(path: Path, topics: Iterable[str] | None, *, times_only: bool = False) -> RawLog:
    """Read an MCAP file: every topic's :class:`TopicInfo`, and the raw messages of
    ``topics`` (compared after :func:`norm_topic`; ``None``: every topic). ``times_only``
    keeps log times (ns) but no payloads (for ``inspect``)."""
    if path.stat().st_size == 0:
        raise LogReadError(f"{path}: file is empty (0 bytes)")
    with open(path, "rb") as fh:
        if fh.read(8) != MAGIC:
            raise LogReadError(f"{path}: not an MCAP file (bad magic bytes at offset 0)")
        mm = mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ)
        try:
            return _Reader(path, mm, topics, times_only).run()
        finally:
            with contextlib.suppress(BufferError):  # payloads are copies; a view may linger
                mm.close()


class _Reader:
    """One pass over an MCAP file: the summary, the data section's records, the chunks."""

    def __init__(
        self, path: Path, mm: mmap.mmap, topics: Iterable[str] | None, times_only: bool
    ) -> None:
        self.path, self.mm, self.size, self.times_only = path, mm, len(mm), times_only
        self.want = None if topics is None else {norm_topic(t) for t in topics}
        self.warnings: list[str] = []
        #: Schema and Channel records by opcode and id: (content bytes, parsed record)
        self.tables: dict[int, dict[int, tuple[bytes, Schema | Channel]]] = {3: {}, 4: {}}
        self.counts: dict[int, int] = {}  # messages seen per channel, and their log-time span
        self.spans: dict[int, tuple[int, int]] = {}
        self.builders: dict[int, TopicBuilder | None] = {}
        self.chunk_index: dict[int, ChunkIndex] = {}
        self.stats: Statistics | None = None
        self.footer, self.lost, self.cut_detail, self.released = False, 0, "", 0
        self.spare: list[U8] = []  # run buffers free again (fresh pages fault in at a cost)
        self.summary_start = self._summary()

    def _summary(self) -> int:
        """Read the summary section when the footer points at a sound one; its start, or 0."""
        mm, size = self.mm, self.size
        if size < 45 or mm[size - 8 :] != MAGIC or mm[size - 37] != Opcode.FOOTER:
            return 0
        self.footer = True
        start, _offsets, crc = struct.unpack_from("<QQI", mm, size - 28)
        if not start:
            return 0  # a footer, and no summary (a writer may leave it out)
        try:
            if not 8 <= start <= size - 37:
                raise ValueError("it lies outside the file")
            if crc and crc32(mm[start : size - 12]) != crc:
                raise ValueError("it fails its CRC check")
            for rec in StreamReader(io.BytesIO(mm[start:]), skip_magic=True).records:
                if isinstance(rec, Schema | Channel):
                    op = Opcode.SCHEMA if isinstance(rec, Schema) else Opcode.CHANNEL
                    self.define(op, rec, b"", f"in the summary (byte {start})")
                elif isinstance(rec, ChunkIndex):
                    self.chunk_index[rec.chunk_start_offset] = rec
                elif isinstance(rec, Statistics):
                    self.stats = rec
        except Exception as exc:  # any damage: read as a log without summary
            self.warnings.append(
                f"{self.path}: the summary section (byte {start}) is damaged ({one_line(exc)}); "
                "read without it"
            )
            self.tables, self.chunk_index, self.stats = {3: {}, 4: {}}, {}, None
            return 0
        return int(start)

    def define(self, op: int, rec: Schema | Channel | None, content: bytes, where: str) -> None:
        """Take a Schema or Channel record (parsed ``rec``, or its ``content`` bytes, found
        ``where``); a damaged one, or an id defined again with other content, is warned
        about and the first definition kept."""
        kind = "Schema" if op == Opcode.SCHEMA else "Channel"
        try:
            if rec is None:
                stream = ReadDataStream(io.BytesIO(content))
                rec = Schema.read(stream) if op == Opcode.SCHEMA else Channel.read(stream)
            out = RecordBuilder()
            rec.write(out)  # written back, it must be the same bytes: nothing cut or left
            if content and out.end()[9:] != content:
                raise ValueError("its fields do not fill the record exactly")
            content = content or out.end()[9:]
        except Exception as exc:
            self.warnings.append(f"{self.path}: damaged {kind} record {where}: {one_line(exc)}")
            return
        if self.tables[op].setdefault(rec.id, (content, rec))[0] != content:
            self.warnings.append(
                f"{self.path}: {kind} {rec.id} {where} redefines it with other content; "
                "kept the first definition"
            )

    def builder(self, cid: int) -> TopicBuilder | None:
        """The builder of channel ``cid`` when its topic is wanted (``None`` otherwise)."""
        if cid in self.builders or cid not in self.tables[Opcode.CHANNEL]:
            return self.builders.get(cid)  # an unknown one is decided once it is defined
        ch = self.tables[Opcode.CHANNEL][cid][1]
        assert isinstance(ch, Channel)
        b = None
        if self.want is None or norm_topic(ch.topic) in self.want:
            b = TopicBuilder(norm_topic(ch.topic), *self._msgtype(ch))
        self.builders[cid] = b
        return b

    def _msgtype(self, ch: Channel) -> tuple[str, str, str]:
        """(normalised type, message encoding, definition text) of a channel."""
        s = self.tables[Opcode.SCHEMA].get(ch.schema_id, (b"", None))[1]
        if not isinstance(s, Schema):
            return "", ch.message_encoding, ""
        return normalize_type_name(s.name), ch.message_encoding, s.data.decode("utf-8", "replace")

    def _add(self, cid: int, buf: U8, offset: I64, length: I64, log_time: I64) -> None:
        """Count channel ``cid``'s messages logged at ``log_time`` (ns); keep their payloads
        ``buf[offset[i]:][:length[i]]`` when the channel is wanted."""
        if not len(log_time):
            return
        lo, hi = self.spans.get(cid, (int(log_time.min()), int(log_time.max())))
        self.spans[cid] = (min(lo, int(log_time.min())), max(hi, int(log_time.max())))
        self.counts[cid] = self.counts.get(cid, 0) + len(log_time)
        if (b := self.builder(cid)) is None or not len(length):
            return
        if self.times_only:
            b.add(buf[:0], np.zeros_like(offset), np.zeros_like(offset), log_time, copy=False)
        elif int(length.min()) == int(length.max()) > 0:  # one payload length: one row gather
            b.take_rows(buf, offset, int(length[0]), log_time)
        else:
            b.add(buf, offset, length, log_time)

    def run(self) -> RawLog:
        """Walk the data section's records, then read what was found, in file order."""
        mm, end = self.mm, self.summary_start or self.size
        pos, gone = 8, set()
        last: _Chunk | None = None
        found: list[_Chunk | tuple[Any, ...]] = []  # + unchunked messages, a cut-off chunk
        head, listed_at = REC.unpack_from, self.chunk_index.get  # the loop's hot names
        while pos + 9 <= end:
            op, ln = head(mm, pos)
            c, listed = pos + 9, listed_at(pos)
            if op == Opcode.MESSAGE_INDEX and last is not None and listed is None and c + ln <= end:
                cid, n = _INDEX.unpack_from(mm, c) if ln >= 6 else (0, -1)
                last[2][cid] = (c + 6, n if 6 + n <= ln else -1)
                pos = c + ln
                continue
            if pos - self.released > 8 << 20:
                self._release(pos)
            if listed is not None and op != Opcode.CHUNK:
                self._fail(pos, None, f"has opcode {op:#04x}, yet the summary lists a chunk there")
                gone.add(pos)
                pos, last = pos + max(listed.chunk_length, 9), None
                continue
            if op == 0 or 0x10 <= op < 0x80 or c + ln > end:
                if op == Opcode.CHUNK and not self.summary_start:
                    found.append(("cut", pos, c, 0))  # read in file order, after the chunks before
                if (pos := self._resync(pos, op, end)) < 0:
                    break
                continue
            if op == Opcode.CHUNK:
                try:
                    hdr: ChunkHeader | str = parse_chunk_header(mm, c, c + ln)
                except (ValueError, struct.error) as exc:
                    hdr = f"has a damaged header ({exc})"
                found.append(last := (pos, hdr, {}))
            elif op in (Opcode.SCHEMA, Opcode.CHANNEL):
                self.define(op, None, mm[c : c + ln], f"at byte {pos}")
            elif op == Opcode.MESSAGE and ln >= 22:
                found.append((c, ln))
            elif op in (Opcode.DATA_END, Opcode.FOOTER):
                break
            if op < 0x80 and op not in (Opcode.MESSAGE_INDEX, Opcode.CHUNK):
                last = None  # a chunk's MessageIndex records follow it (private ones between)
            pos = c + ln
        self._release(self.size)
        self.released = 0
        self._read(found)
        for rec in sorted(set(self.chunk_index) - gone - {f[0] for f in found if len(f) == 3}):
            self._fail(rec, None, "is listed in the summary, but no Chunk record is there")
        return self._result()

    def _resync(self, pos: int, op: int, end: int) -> int:
        """Where to go on after no valid record at ``pos``: the next chunk the summary lists
        (the chunks skipped are reported by :meth:`run`), or -1 (the end)."""
        nxt = min((s for s in self.chunk_index if s > pos), default=-1)
        where = f"{self.path}: no valid MCAP record at byte {pos} (opcode {op}); "
        if not self.summary_start:
            self.lost = self.size - pos
        elif 0 <= nxt < end:
            self.warnings.append(f"{where}skipped {nxt - pos} damaged bytes to the chunk at {nxt}")
        else:
            self.warnings.append(f"{where}the {end - pos} bytes up to the summary are lost")
        return nxt if self.summary_start and nxt < end else -1

    def _partial_chunk(self, rec: int, c: int) -> None:
        """A chunk cut off by the end of the file: recover its decompressible prefix."""
        try:
            hdr = parse_chunk_header(self.mm, c, self.size, partial=True)
            data = decompress_prefix(hdr.compression, self.mm[hdr.data_at : self.size])
        except Exception:  # nothing recoverable: the cut is reported as lost bytes
            return
        n = self._walk(rec, np.frombuffer(data, dtype=np.uint8), "", cut=True)
        self.cut_detail = (
            f"the last chunk, at byte {rec}, is cut off; recovered {n} message(s) "
            "from its decompressible prefix"
        )

    def _entries(self, index: _Index) -> _Ents | None:
        """Per channel, the (log time, record offset) uint64 rows; ``None`` if malformed."""
        out = {}
        for cid, (at, n) in index.items():
            if n < 0 or n % 16 or at + n > self.size:
                return None
            out[cid] = np.frombuffer(self.mm, dtype="<u8", count=n // 8, offset=at).reshape(-1, 2)
        return out

    def _read(self, found: list[_Chunk | tuple[Any, ...]]) -> None:
        """Read the chunks and unchunked messages in file order: runs of chunks are
        decompressed on the threads, up to ``THREADS`` runs ahead of the one being read."""
        pending: deque[tuple[list[_Chunk], I64, _Job]] = deque()
        run: list[_Chunk] = []
        sizes = [0]  # where each chunk of the run starts in its buffer, and the buffer's size
        with ThreadPoolExecutor(THREADS, thread_name_prefix="uwval-mcap") as pool:

            def submit(keep: int) -> None:
                if run:
                    fits = [k for k, b in enumerate(self.spare) if len(b) >= sizes[-1]]
                    buf = (
                        self.spare.pop(fits[0])
                        if fits
                        else np.empty(max(sizes[-1], 2 * BATCH_BYTES), np.uint8)
                    )
                    at = np.array(sizes, np.int64)
                    pending.append((list(run), at, pool.submit(self._inflate, list(run), at, buf)))
                    run.clear()
                    sizes[:] = [0]
                while len(pending) > keep:
                    self._take(*pending.popleft())

            for item in found:
                if len(item) != 3:  # an unchunked message, a cut-off chunk: what comes before first
                    submit(0)
                if item[0] == "cut":
                    self._partial_chunk(item[1], item[2])
                elif len(item) == 2:
                    c, ln = item
                    cid, _seq, t = struct.unpack_from("<HIQ", self.mm, c)
                    data = np.frombuffer(self.mm[c + 22 : c + ln], dtype=np.uint8)
                    self._add(cid, data, np.zeros(1, np.int64), np.array([ln - 22]), np.array([t]))
                elif isinstance(item[1], str):
                    self._fail(item[0], item[2], item[1])
                else:
                    run.append(item)
                    sizes.append(sizes[-1] + item[1].usize)
                    if sizes[-1] >= BATCH_BYTES:
                        submit(THREADS)
            submit(0)

    def _inflate(self, run: list[_Chunk], at: I64, buf: U8) -> tuple[U8, list[tuple[str, str]]]:
        """Decompress and CRC-check a run of chunks into ``buf`` (chunk k from ``at[k]``; on
        an inflate thread)."""
        heads = [h for _r, h, _i in run if isinstance(h, ChunkHeader)]
        zstd = zstandard.ZstdDecompressor()  # one context for the run (a new one costs)
        return buf, [
            inflate_into(self.mm, h, buf[at[k] : at[k + 1]], zstd) for k, h in enumerate(heads)
        ]

    def _take(self, run: list[_Chunk], at: I64, job: _Job) -> None:
        """Add the wanted messages of a decompressed run: every index checked at once; when
        anything in the run is off, chunk by chunk (each reports what is wrong)."""
        whole, status = job.result()
        buf, ents = whole[: at[-1]], [self._entries(index) for _r, _h, index in run]
        if any(what for what, _c in status) or self._indexed(run, buf, at, ents):
            for k, (rec, _hdr, index) in enumerate(run):
                (what, cause), one = status[k], buf[at[k] : at[k + 1]]
                if what:
                    self._fail(rec, index, what, cause)
                elif why := self._indexed([run[k]], one, at[k : k + 2] - at[k], ents[k : k + 1]):
                    bad = f"disagrees with its records ({why})" if ents[k] else "is malformed"
                    self._walk(rec, one, bad if index else "")
        self.spare.append(whole)  # whatever was kept of it was copied out
        self._release(max([run[-1][0], *(a + n for a, n in run[-1][2].values())]))

    def _release(self, upto: int) -> None:
        """Drop the file map's pages below ``upto`` from the resident set: the kernel maps
        64 kB around each page read (the walk touches one per chunk), and mapped pages
        count as this process's memory. The bytes stay in the page cache."""
        stop = upto // mmap.PAGESIZE * mmap.PAGESIZE
        if stop > self.released and hasattr(self.mm, "madvise"):
            self.mm.madvise(mmap.MADV_DONTNEED, self.released, stop - self.released)
            self.released = stop

    def _indexed(self, run: list[_Chunk], buf: U8, at: I64, ents: list[_Ents | None]) -> str:
        """Add the messages of chunks lying end to end in ``buf`` (chunk k from byte
        ``at[k]``) located by their indexes when these check out: "", else why not."""
        if not all(ents):
            return "no usable index"
        groups: dict[int, list[tuple[int, NDArray[np.uint64]]]] = {}
        for k, e in enumerate(ents):  # every channel's entries together, chunk by chunk
            for cid, rows in (e or {}).items():
                groups.setdefault(cid, []).append((k, rows))
        spans, lo = [], 0
        for cid, parts in groups.items():
            spans.append((cid, lo, lo := lo + sum(len(r) for _k, r in parts)))
        parts = [p for ps in groups.values() for p in ps]
        chunk = np.repeat([k for k, _r in parts], [len(r) for _k, r in parts])
        rows = np.concatenate([r for _k, r in parts])
        reason, ck = check_index(buf, rows, chunk, spans, at)
        if reason:
            return reason
        for op, a, b in ck.tables:
            k = int(np.searchsorted(at, a, "right")) - 1
            self.define(op, None, buf[a:b].tobytes(), _inside(run[k][0], a - 9 - int(at[k])))
        for cid, lo, hi in spans:
            times = rows[lo:hi, 0].astype(np.int64)
            self._add(cid, buf, ck.rec[lo:hi] + 31, ck.length[lo:hi] - 22, times)
        return ""

    def _walk(self, rec: int, buf: U8, why: str, *, cut: bool = False) -> int:
        """Read a chunk by walking its records (it has no index, or ``why`` not a right
        one, or is ``cut`` off); how many messages were found."""
        where = f"{self.path}: MCAP chunk at byte {rec}"
        if why:
            self.warnings.append(f"{where}: its MessageIndex {why}; read by walking its records")
        walk = walk_records(buf, 0, len(buf))
        for op, a, b in walk.tables:
            self.define(op, None, buf[a:b].tobytes(), _inside(rec, a - 9))
        for cid, (offs, lens, times) in walk.messages.items():
            self._add(cid, buf, np.array(offs), np.array(lens), np.array(times, dtype=np.int64))
        if walk.stop < len(buf) and not cut:
            self.warnings.append(
                f"{where}: record at byte {walk.stop} of the decompressed chunk is damaged "
                f"({walk.reason}); the chunk's last {len(buf) - walk.stop} bytes were not read"
            )
        return sum(len(m[2]) for m in walk.messages.values())

    def _fail(
        self, rec: int, index: _Index | None, what: str, cause: str = "damaged_chunk"
    ) -> None:
        """Warn that the chunk at ``rec`` could not be read and count its messages dropped:
        from its MessageIndex records, or (``index`` None) the ones its ChunkIndex lists."""
        if index is None:
            index = {}
            for cid, off in self.chunk_index[rec].message_index_offsets.items():
                ok = off + 15 <= self.size and self.mm[off] == Opcode.MESSAGE_INDEX
                if ok and _U16.unpack_from(self.mm, off + 9)[0] == cid:
                    index[cid] = (off + 15, _U32.unpack_from(self.mm, off + 11)[0])
        ents, parts = self._entries(index) or {}, []
        for cid, e in ents.items():
            if len(e):
                none = np.zeros(0, np.int64)  # counted, not read
                self._add(cid, none.view(np.uint8), none, none, e[:, 0].astype(np.int64))
            if (b := self.builder(cid)) is not None and len(e):
                b.drop(cause, len(e))
                parts.append(f"{len(e)} on {b.name}")
        lost = (
            f"{sum(len(e) for e in ents.values())} message(s) dropped"
            if ents
            else "message count unknown (no usable index)"
        )
        self.warnings.append(
            f"{self.path}: MCAP chunk at byte {rec} {what}; {lost}"
            + (f" ({', '.join(parts)})" if parts else "")
        )

    def _result(self) -> RawLog:
        """The RawLog: topics, messages, and what the summary's counts say is missing."""
        channels = self.tables[Opcode.CHANNEL]
        expected = self.stats.channel_message_counts if self.stats is not None else {}
        for cid, n in sorted(expected.items()):
            if (got := self.counts.get(cid, 0)) < n:
                b = self.builder(cid)
                name = b.name if b is not None else f"channel {cid}"
                self.warnings.append(
                    f"{self.path}: the summary counts {n} messages on {name}, "
                    f"{got} were found in the data section"
                )
                if b is not None:
                    b.drop("missing", n - got)
        for cid in sorted(set(self.counts) - set(channels)):
            self.warnings.append(
                f"{self.path}: {self.counts[cid]} message(s) on channel {cid}, which no "
                "Channel record defines, were not read"
            )
        infos = []
        for cid, (_content, ch) in sorted(channels.items()):
            assert isinstance(ch, Channel)
            lo, hi = self.spans.get(cid, (0, 0))
            typ = self._msgtype(ch)[0]
            infos.append(TopicInfo(norm_topic(ch.topic), typ, self.counts.get(cid, 0), lo, hi))
        built = [b.build() for b in self.builders.values() if b is not None]
        log = RawLog(self.path, merge_infos(infos), merge_topics(built), lost_bytes=self.lost)
        log.warnings, log.cut_detail = self.warnings, self.cut_detail
        if not self.footer:
            log.unclean = "no summary or footer: the writer did not finish"
        return log


def _inside(chunk: int, at: int) -> str:
    """Where a record lies inside a chunk, for messages."""
    return f"at byte {at} of the records of the chunk at byte {chunk}"
