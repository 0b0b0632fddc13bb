"""Fast MCAP scanner: whole chunks in, per-topic payload buffers out, nothing trusted blindly.

The mcap library hands out one Python object per message; at a million messages that costs
seconds. This scanner walks only the top-level records (one step per chunk), decompresses each
chunk that holds a wanted channel once (zstd / lz4), checks it against its CRC, and locates the
wanted channels' messages from the chunk's MessageIndex records. Two paths do that, with the
same result: runs of chunks read in C (``scan_chunks``, see :mod:`uwval.io.mcap_runs`: its own
threads decompress, check and walk, with the GIL released; one call reads run after run,
planning each while the one before is read), which leaves whatever it would not read exactly as
the batched path does (damaged or odd chunks, new Schema/Channel records, lz4, chunks without
index, logs without summary) to the batched path: chunks decompressed on inflate threads and
located by one C walk of each (``_mcapwalk``, optional), else with numpy, on the reading
thread.

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
import os
import struct
import threading
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from uwval.errors import LogReadError
from uwval.io import mcap_runs
from uwval.io.crc import crc32
from uwval.io.mcap_chunk import (
    ChunkHeader,
    Tables,
    WalkResult,
    check_index,
    decompress,
    decompress_prefix,
    parse_chunk_header,
    walk_records,
)
from uwval.io.mcap_records import (
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
)
from uwval.io.mcap_records import summary_start as summary_start_of
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

if TYPE_CHECKING:
    from concurrent.futures import Future as Job
    from concurrent.futures import ThreadPoolExecutor as Workers

try:  # the optional C check of a chunk against its index (uwval/io/_mcapwalk.c)
    from uwval.io import _mcapwalk
except ImportError:  # pragma: no cover - installs without a C compiler: the numpy check
    _mcapwalk = None  # type: ignore[assignment]

#: Whether batched chunks are checked by the C walk on the inflate thread: it is built and
#: ``UWVAL_NO_ACCELERATOR`` is not set (tests and benchmarks check both paths; without it the
#: numpy :func:`check_index` checks every batch on the reading thread, with the same result).
USE_MATCH = _mcapwalk is not None and not os.environ.get("UWVAL_NO_ACCELERATOR")
#: Schema/Channel records a chunk may hold for the C walk (more: the numpy check reads it)
MATCH_TABLES = 256
#: Whether runs of chunks are read in C (``_mcapwalk.scan_chunks``, see
#: :mod:`uwval.io.mcap_runs`: zstd and the CRC from C, on POSIX threads, no GIL hand-over per
#: chunk); needs the C walk and libzstd (found at the first read). The batched path below
#: reads the rest (lz4 chunks, chunks without index, logs without summary) and every chunk
#: the C call leaves to it.
USE_SCAN = USE_MATCH
SCAN_FILE_BYTES = mcap_runs.SCAN_FILE_BYTES
SCAN_SLOT_BYTES = mcap_runs.SCAN_SLOT_BYTES
#: the rows and payloads one scan_chunks call holds at most before it returns them
SCAN_HOLD_BYTES = mcap_runs.SCAN_HOLD_BYTES
SCAN_BUDGET, SCAN_CHUNK, SCAN_OTHER = (
    mcap_runs.SCAN_BUDGET,
    mcap_runs.SCAN_CHUNK,
    mcap_runs.SCAN_OTHER,
)


_MSG = struct.Struct("<HIQQ")
#: decompressed bytes of chunks read together (see ``_Scanner.queue``): a few MB keeps the
#: per-chunk numpy calls off small chunks while the batch buffers stay small (cache-sized)
BATCH_BYTES = 2 << 20
#: larger chunks (or a damaged size field claiming more) are read alone, never into a batch
#: buffer sized by their header
BATCH_MAX = mcap_runs.MAX_CHUNK
#: a queued chunk: (record start, content start, length, index locations, entries, where
#: its records go in the batch buffer (lo, hi), the job decompressing them there)
_Queued = tuple[
    int,
    int,
    int,
    dict[int, tuple[int, int]],
    "dict[int, np.ndarray]",
    int,
    int,
    "_Part",
]


class _Part:
    """A queued chunk's share of its batch's inflate job: its result, once the batch is
    handed to the inflate thread(s) (:meth:`_Scanner._submit`)."""

    __slots__ = ("job", "k")

    def __init__(self, k: int) -> None:
        self.job: Job[list[bool | _Matched]] | None = None
        self.k = k

    def result(self) -> bool | _Matched:
        assert self.job is not None, "a chunk read before its batch was handed over"
        return self.job.result()[self.k]


@dataclass
class _Matched:
    """A chunk checked against its index by the C walk (``_mcapwalk.match_chunk``) on the
    inflate thread: per indexed channel (``groups``: id, entries, first row in ``out`` or -1
    when not wanted), the wanted records (``out`` rows: payload start in the batch buffer, or
    record start in the chunk when only times are read; log time; record length), each
    log-time span, record lengths and payloads (``spans`` rows: min and max log time, min
    and max record length, where the payloads start in the batch buffer) and the
    Schema/Channel records (``tables``)."""

    groups: list[tuple[int, np.ndarray, int]]
    out: np.ndarray
    spans: np.ndarray
    tabs: np.ndarray
    #: where the wanted payloads go: the chunk's slot in the batch buffer, which starts at
    #: ``payload_at`` (None when only times are read)
    payload: np.ndarray | None
    payload_at: int
    #: the chunk's Schema/Channel records (opcode, content), in file order
    tables: list[tuple[int, bytes]] = field(default_factory=list)


@dataclass
class _Summary:
    """What the summary section says: tables, per-channel message counts, chunk starts."""

    tables: Tables
    counts: dict[int, int] = field(default_factory=dict)
    chunk_starts: list[int] = field(default_factory=list)
    start: int = 0


def _read_summary(mm: Buffer, size: int, path: Path, warns: list[str]) -> _Summary | None:
    """The summary section, if the file has a valid one (footer, magic, CRC when present)."""
    summary_start, damage = summary_start_of(mm, size)
    if damage:
        warns.append(f"{path}: {damage}")
    if not summary_start:
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
        scanner = _Scanner(path, mm, size, topics, times_only)
        try:
            return scanner.run()
        finally:
            if scanner.pool is not None:  # no job may read the map once it is closed
                scanner.pool.shutdown(cancel_futures=True)
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
        #: complete chunks waiting to be read together, being decompressed into ``mem``
        #: (``fill`` bytes used), and the full batch before them (in ``sealed_mem``), read
        #: when this one is full; ``spare`` is the buffer of the batch read last
        self.batch: list[_Queued] = []
        self.sealed: list[_Queued] = []
        empty = np.empty(0, dtype=np.uint8)
        self.mem, self.sealed_mem = empty, empty
        self.spare: np.ndarray | None = None
        self.fill = 0
        self.pool: Workers | None = None
        self.inflaters = 1
        #: the batch being filled: each chunk's (header, records slot, walk plan)
        self.work: list[tuple[ChunkHeader, np.ndarray, _Matched | None]] = []
        self.local = threading.local()  # each inflate thread's chunk buffer (_scratch)
        #: runs of chunks go to the C call (logs with a summary: it tells which chunks hold
        #: no wanted channel); ``scan_skip``: a chunk it left to the batched path
        self.scan = USE_SCAN and self.summary is not None and mcap_runs.scan_ready()
        self.scan_skip = -1
        self.scan_threads = 0
        self.scan_maps: tuple[int, int, bytes] | None = None
        self.scan_ws: object = None  # the C threads' buffers, kept from call to call

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
                self.queue(*pending, indexes)
                pending, indexes = None, {}
                if not self.batch and not self.sealed:
                    self.released = release_pages(mm, self.released, pos)
            if op not in (OP_CHUNK, OP_MESSAGE_INDEX) and (self.batch or self.sealed):
                self.flush()  # records between chunks apply in file order
            if (op == 0 or op > 0x20 or c + ln > end) and (self.batch or self.sealed):
                self.flush()  # the queued chunks come first: their messages and warnings
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
                if self.scan and pos != self.scan_skip:
                    nxt = self._scan(pos, end)
                    if nxt is not None:
                        pos = nxt
                        continue
                # a chunk's own MessageIndex records follow it (ones whose chunk was lost
                # to damage are not this chunk's)
                pending, indexes = (pos, c, ln), {}
            elif op == OP_MESSAGE_INDEX and ln >= 6 and pending is not None:
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
            self.queue(*pending, indexes)
        self.flush()
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

    # ------------------------------------------------------------------ runs of chunks (C)
    def _maps(self) -> bytes:
        """The per-id table of ``scan_chunks`` (:func:`uwval.io.mcap_runs.scan_maps`) for
        the channels and schemas known now."""
        key = (len(self.tables.channels), len(self.tables.schemas))
        if self.scan_maps is None or self.scan_maps[:2] != key:
            channels = {cid: norm_topic(ch.topic) for cid, ch in self.tables.channels.items()}
            maps = mcap_runs.scan_maps(channels, self.tables.schemas, self.want)
            self.scan_maps = (*key, maps)
        return self.scan_maps[2]

    def _scan(self, pos: int, end: int) -> int | None:
        """Read the runs of chunks from ``pos`` on by one ``_mcapwalk.scan_chunks`` call; where the
        reader goes on, or None when nothing was read (the chunk at ``pos`` is then read by
        the batched path)."""
        assert _mcapwalk is not None
        if self.batch or self.sealed:
            self.flush()  # chunks are read in file order
        maps = self._maps()
        if not self.scan_threads:
            self.scan_threads = 2 if (os.cpu_count() or 1) > 1 else 1
        if self.scan_ws is None:
            self.scan_ws = _mcapwalk.scan_workspace()
        # run after run in one call, until SCAN_HOLD_BYTES of results are held (their
        # memory is then reused by the next call's); each run drops the map pages read
        # before it while its other thread decompresses
        results, released = _mcapwalk.scan_chunks(
            self.scan_ws,
            self.mm,
            pos,
            end,
            maps,
            SCAN_FILE_BYTES,
            SCAN_SLOT_BYTES,
            self.scan_threads,
            not self.times_only,
            BATCH_MAX,
            self.released,
            0,
            True,
            SCAN_HOLD_BYTES,
        )
        self.released = max(self.released, released)
        stop, nxt = results[-1][:2]
        n = sum(r[2] for r in results)
        if n:
            self._from_scans(results)
        del results  # the runs' buffers go: their messages were copied to the topics
        if stop != SCAN_BUDGET:  # the reader goes on from here: what was read may go
            self.released = release_pages(self.mm, self.released, nxt)
        if stop == SCAN_OTHER:
            self.scan = False
        elif stop == SCAN_CHUNK:
            self.scan_skip = nxt
        return nxt if n else None

    def _from_scans(self, runs: list[mcap_runs.ScanResult]) -> None:
        """Add what the runs of ``scan_chunks`` calls read: per run and channel (id, count,
        log-time span, min and max record length, its rows; the run's ``packed`` holds its
        payloads end to end, channel after channel). Each channel's runs are added in file
        order, all at once: a pose topic's (one payload length) blocks by one copy each into
        its buffer, with one array of log times."""
        recs: list[np.ndarray] = []
        bufs: list[np.ndarray | None] = []
        per: dict[int, list[tuple[int, list[int]]]] = {}  # cid -> (run, its stats row) each
        for k, (_stop, _nxt, _n, rows, packed, stats) in enumerate(runs):
            recs.append(np.frombuffer(rows, dtype=np.int64).reshape(-1, 3))
            bufs.append(np.frombuffer(packed, dtype=np.uint8) if packed is not None else None)
            for row in np.frombuffer(stats, dtype=np.int64).reshape(-1, 9).tolist():
                per.setdefault(row[0], []).append((k, row))
        for cid, entries in per.items():
            self.tables.seen_span(
                cid,
                sum(r[1] for _k, r in entries),
                min(r[2] for _k, r in entries),
                max(r[3] for _k, r in entries),
            )
            wanted = [(k, r) for k, r in entries if r[7]]
            b = self.builder(cid) if wanted else None
            if b is None:
                continue
            # the log times of all its runs, in order (a copy: a view would keep every
            # run's rows alive)
            times = [recs[k][r[6] : r[6] + r[7], 1] for k, r in wanted]
            log_time = times[0].copy() if len(times) == 1 else np.concatenate(times)
            if bufs[wanted[0][0]] is None:  # times only
                z = np.zeros(len(log_time), np.int64)
                b.add(np.empty(0, np.uint8), z, z, log_time, copy=False)
                continue
            len_lo = wanted[0][1][4]
            if len_lo > 22 and all(r[4] == r[5] == len_lo for _k, r in wanted):
                # one payload length (a pose topic): each run's rows lie end to end
                pieces = [(buf, r[8], r[7]) for k, r in wanted if (buf := bufs[k]) is not None]
                b.take_pieces(pieces, len_lo - 22, log_time)
                continue
            at = 0
            for k, r in wanted:
                rr = recs[k][r[6] : r[6] + r[7]]
                buf = bufs[k]
                assert buf is not None
                b.add(buf, rr[:, 0], rr[:, 2] - 22, log_time[at : at + r[7]].copy())
                at += r[7]

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

    def queue(self, rec: int, c: int, ln: int, indexes: dict[int, tuple[int, int]]) -> None:
        """Take one complete Chunk record (and its MessageIndex records): chunks whose index
        and header look usable are batched (:meth:`_seal`), any other is read alone by
        :meth:`chunk`.

        A batch's chunks are decompressed and CRC-checked on the inflate thread(s) (zstd and
        the CRC release the GIL) while this thread reads the batch before it: a batch is read
        when the next one is full, so the two overlap. With the C walk, each chunk's index is
        checked there too and only the wanted payloads reach the batch buffer; without it,
        the records go to the batch buffer for the numpy check.
        """
        ents = self._entries(indexes)
        if self._skip(ents):
            return
        hdr = None
        if ents and any(len(e) for e in ents.values()):
            try:
                hdr = parse_chunk_header(self.mm, c, c + ln)
            except ValueError:
                hdr = None
        if hdr is None or hdr.compression not in ("zstd", "lz4", "") or hdr.usize > BATCH_MAX:
            self.flush()
            self.chunk(rec, c, ln, indexes)
            return
        assert ents is not None
        u = hdr.usize
        if self.batch and self.fill + u > self.mem.shape[0]:
            self._seal()
        if not self.batch:
            self.mem, self.fill = self._buffer(u), 0
        lo, hi = self.fill, self.fill + u
        self.fill = hi
        plan = self._plan(ents, lo, hi) if USE_MATCH else None
        job = _Part(len(self.work))
        self.work.append((hdr, self.mem[lo:hi], plan))
        self.batch.append((rec, c, ln, indexes, ents, lo, hi, job))
        if self.fill >= BATCH_BYTES:
            self._seal()

    def _submit(self) -> None:
        """Hand the chunks of the batch being filled to the inflate thread(s): one job per
        thread for the whole batch (a job per chunk costs more in hand-overs than a small
        chunk takes to decompress)."""
        work, self.work = self.work, []
        if not work:
            return
        if self.pool is None:
            from concurrent.futures import ThreadPoolExecutor

            # with a second CPU, two threads decompress (and walk) while this one reads:
            # chunks of compressible poses make decompression most of the work
            self.inflaters = 2 if (os.cpu_count() or 1) > 1 else 1
            self.pool = ThreadPoolExecutor(self.inflaters, thread_name_prefix="uwval-mcap-inflate")
        step = -(-len(work) // self.inflaters)
        jobs = [
            self.pool.submit(self._inflate_all, work[i : i + step])
            for i in range(0, len(work), step)
        ]
        for item in self.batch:
            part = item[-1]
            part.job, part.k = jobs[part.k // step], part.k % step

    def _inflate_all(
        self, work: list[tuple[ChunkHeader, np.ndarray, _Matched | None]]
    ) -> list[bool | _Matched]:
        """:meth:`_inflate_into` for chunks one after the other (an inflate thread's job)."""
        return [self._inflate_into(hdr, dest, plan) for hdr, dest, plan in work]

    def _buffer(self, need: int) -> np.ndarray:
        """A batch buffer of at least ``need`` bytes: the one of the batch read last (free
        again: whatever is kept of a batch is copied out of it) or a new one (fresh pages
        fault in on first touch, a cost per byte as large as decompressing). Each chunk has a
        slot of its records' size: the records (numpy check) or the wanted payloads the C walk
        copies out of them (pages never written are never made resident)."""
        spare, self.spare = self.spare, None
        if spare is not None and spare.shape[0] >= need:
            return spare
        return np.empty(max(2 * BATCH_BYTES, need), dtype=np.uint8)

    def _seal(self) -> None:
        """The batch being filled is complete: start decompressing it, and read the one
        before it meanwhile (its chunks are decompressed by now)."""
        self._submit()
        sealed, mem = self.sealed, self.sealed_mem
        self.sealed, self.sealed_mem = self.batch, self.mem
        self.batch, self.fill = [], 0
        self._read_items(sealed, mem)
        self.spare = mem

    def _plan(self, ents: dict[int, np.ndarray], lo: int, hi: int) -> _Matched:
        """What the C walk of a chunk placed at ``lo:hi`` in the batch buffer fills in: rows
        for the channels wanted (or not known yet: their Channel record may be in this chunk)
        and, unless only times are read, their payloads (into the chunk's slot of the batch
        buffer: its records go to a buffer of the inflate thread instead, and a chunk's
        payloads are never larger than its records)."""
        groups: list[tuple[int, np.ndarray, int]] = []
        rows = 0
        for cid, e in ents.items():
            want = cid not in self.tables.channels or self.builder(cid) is not None
            groups.append((cid, e, rows if want else -1))
            rows += len(e) if want else 0
        return _Matched(
            groups,
            np.empty((rows, 3), dtype=np.int64),
            np.empty((len(groups), 5), dtype=np.int64),
            np.empty((MATCH_TABLES, 3), dtype=np.int64),
            None if self.times_only else self.mem[lo:hi],
            lo,
        )

    def _inflate_into(
        self, hdr: ChunkHeader, dest: np.ndarray, plan: _Matched | None = None
    ) -> bool | _Matched:
        """Decompress a chunk's records and check its CRC (runs on the inflate thread).

        Without ``plan`` (no C walk) the records go to ``dest`` (exactly their declared
        size) for the numpy check: True. With it, they go to a small buffer of this thread,
        reused chunk after chunk (written while it stays in this core's cache; a stored
        chunk is walked in place in the file map), and the C walk checks the index there
        and copies the wanted payloads out: the filled ``plan``. False when anything is off
        (or the walk does not confirm the index): the chunk is then read alone by
        :meth:`chunk`, which checks it the numpy way and says what is wrong."""
        if plan is None or _mcapwalk is None:
            return self._inflate_checked(hdr, dest)
        try:
            if hdr.compression == "":
                records: np.ndarray = np.frombuffer(
                    self.mm, dtype=np.uint8, count=hdr.data_len, offset=hdr.data_at
                )
                if hdr.data_len != hdr.usize or (hdr.crc and crc32(records) != hdr.crc):
                    return False
            else:
                records = self._scratch(hdr.usize)
                if not self._inflate_checked(hdr, records):
                    return False
            args = () if plan.payload is None else (plan.payload, plan.payload_at)
            code, n_tab = _mcapwalk.match_chunk(
                records, 0, plan.groups, plan.out, plan.spans, plan.tabs, *args
            )
            if code:
                return False
            plan.tables = [
                (int(op), bytes(records[a:b])) for op, a, b in plan.tabs[:n_tab].tolist()
            ]
        except Exception:  # damaged input in any form: the lone read reports it
            return False
        return plan

    def _scratch(self, size: int) -> np.ndarray:
        """This inflate thread's buffer for one chunk's records (``size`` bytes of it)."""
        buf: np.ndarray | None = getattr(self.local, "buf", None)
        if buf is None or buf.shape[0] < size:
            buf = self.local.buf = np.empty(max(size, 1 << 20), dtype=np.uint8)
        return buf[:size]

    def _inflate_checked(self, hdr: ChunkHeader, dest: np.ndarray) -> bool:
        """Decompress a chunk's records into ``dest`` and check its CRC (inflate thread)."""
        try:
            with memoryview(self.mm)[hdr.data_at : hdr.data_at + hdr.data_len] as src:
                if hdr.compression == "zstd":
                    import zstandard

                    out = dest.data  # a memoryview of the (contiguous) slice
                    got = 0
                    dctx = getattr(self.local, "dctx", None)
                    if dctx is None:  # one decompression context per inflate thread
                        dctx = self.local.dctx = zstandard.ZstdDecompressor()
                    with dctx.stream_reader(src) as reader:
                        while got < len(out):
                            n = reader.readinto(out[got:])
                            if not n:
                                break
                            got += n
                        if got != len(out) or reader.read(1):
                            return False  # shorter or longer than its header says
                elif hdr.compression == "":  # stored: copied into place once
                    if len(src) != dest.shape[0]:
                        return False
                    dest[:] = np.frombuffer(src, dtype=np.uint8)
                else:  # lz4: the lone path's decompression, copied into place
                    data = decompress(hdr.compression, src, 0, len(src), hdr.usize)
                    if len(data) != dest.shape[0]:
                        return False
                    dest[:] = np.frombuffer(data, dtype=np.uint8)
            return not hdr.crc or crc32(dest) == hdr.crc
        except Exception:  # damaged input in any form: the lone read reports it
            return False

    def _skip(self, ents: dict[int, np.ndarray] | None) -> bool:
        """Whether a chunk holds no wanted channel (known from the summary): its messages
        are then counted from its index, and the chunk is not decompressed."""
        if self.summary is None or not ents:
            return False
        if not all(cid in self.tables.channels for cid in ents):
            return False
        if any(self.builder(cid) is not None for cid in ents):
            return False
        for cid, e in ents.items():
            self.tables.seen(cid, e[:, 0].astype(np.int64))
        return True

    def chunk(self, rec: int, c: int, ln: int, indexes: dict[int, tuple[int, int]]) -> None:
        """Read one complete Chunk record (and its MessageIndex records) into the builders."""
        ents = self._entries(indexes)
        if self._skip(ents):
            return
        data = self._inflate(c, ln)
        if isinstance(data, tuple):
            self._fail(rec, ents, *data)
            return
        self._records(rec, np.frombuffer(data, dtype=np.uint8), ents, indexes)

    def _inflate(self, c: int, ln: int) -> bytes | tuple[str, str]:
        """A chunk's records, decompressed and CRC-checked; or (what is wrong, drop cause)."""
        try:
            hdr = parse_chunk_header(self.mm, c, c + ln)
        except ValueError as exc:
            return f"damaged chunk header ({exc})", "damaged_chunk"
        try:
            data = decompress(hdr.compression, self.mm, hdr.data_at, hdr.data_len, hdr.usize)
        except LogReadError as exc:
            return str(exc), "damaged_chunk"
        if len(data) != hdr.usize:
            return (
                f"decompresses to {len(data)} bytes, its header says {hdr.usize}",
                "damaged_chunk",
            )
        if hdr.crc and crc32(data) != hdr.crc:
            return "fails its CRC check", "crc_mismatch"
        return data

    def _fail(self, rec: int, ents: dict[int, np.ndarray] | None, what: str, cause: str) -> None:
        """Warn that the chunk at ``rec`` could not be read; count its messages dropped."""
        sep = " " if what == "fails its CRC check" else ": "
        self.warnings.append(
            f"{self.path}: MCAP chunk at byte {rec}{sep}{what}; {self._drop(ents, cause)}"
        )

    def _records(
        self,
        rec: int,
        buf: np.ndarray,
        ents: dict[int, np.ndarray] | None,
        indexes: dict[int, tuple[int, int]],
    ) -> None:
        """Add one decompressed chunk's wanted messages (its records are ``buf``, uint8):
        located by its index when that checks out against the records, else by walking the
        records (with a warning)."""
        where = f"{self.path}: MCAP chunk at byte {rec}"
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
        size = int(buf.shape[0])
        walk = walk_records(buf, 0, size)
        self._from_walk(buf, walk, rec)
        if walk.stop < size:
            self.warnings.append(
                f"{where}: record at byte {walk.stop} of the decompressed chunk is damaged "
                f"({walk.reason}); the chunk's last {size - walk.stop} bytes were not read"
            )

    def flush(self) -> None:
        """Read every queued chunk now, in file order (a record that follows them, or the
        end of the file, must see them read)."""
        self._submit()
        sealed, smem, batch, bmem = self.sealed, self.sealed_mem, self.batch, self.mem
        self.sealed, self.batch, self.fill = [], [], 0
        self._read_items(sealed, smem)
        self._read_items(batch, bmem)

    def _read_items(self, items: list[_Queued], mem: np.ndarray) -> None:
        """Read queued chunks (decompressed into ``mem``), in file order.

        The ones that decompressed and passed their CRC are checked and copied from
        together (one index check and one row gather per channel for the whole run of them,
        not per chunk). A chunk that did not is read alone by :meth:`chunk` (which reports
        what is wrong), after the chunks before it.
        """
        run: list[_Queued] = []
        for item in items:
            if item[-1].result():
                run.append(item)
                continue
            self._read_run(run, mem)
            run = []
            self.chunk(*item[:4])
        self._read_run(run, mem)
        if items:
            _rec, last_c, last_ln = items[-1][:3]
            self.released = release_pages(self.mm, self.released, last_c + last_ln)

    def _read_run(self, run: list[_Queued], mem: np.ndarray) -> None:
        """Add the wanted messages of chunks lying end to end in ``mem``, checking their
        indexes together; when anything in them is off, each chunk is read (and reported)
        on its own instead."""
        if not run:
            return
        matched = [item[-1].result() for item in run]
        if all(isinstance(m, _Matched) for m in matched):
            self._from_matched(run, [m for m in matched if isinstance(m, _Matched)], mem)
            return
        base = run[0][5]
        buf = mem[base : run[-1][6]]
        if len(run) == 1:
            rec, _c, _ln, indexes, ents, _lo, _hi, _job = run[0]
            self._records(rec, buf, ents, indexes)
            return
        ends = np.array([hi - base for *_, hi, _job in run], dtype=np.int64)
        bases = np.array([lo - base for *_, lo, _hi, _job in run], dtype=np.int64)
        per: dict[int, tuple[list[np.ndarray], list[int]]] = {}
        for k, item in enumerate(run):
            for cid, e in item[4].items():
                arrs, ks = per.setdefault(cid, ([], []))
                arrs.append(e)
                ks.append(k)
        joined: dict[int, np.ndarray] = {}
        limits = []
        for cid, (arrs, ks) in per.items():
            counts = np.array([len(e) for e in arrs], dtype=np.int64)
            e = np.concatenate(arrs)
            e[:, 1] += np.repeat(bases[ks], counts).astype(np.uint64)
            joined[cid] = e
            limits.append(np.repeat(ends[ks], counts))
        reason, gaps = check_index(buf, joined, limit=np.concatenate(limits), cuts=ends[:-1])
        first_end = int(ends[0])
        known = set(self.tables.channels), set(self.tables.schemas)
        # Schema/Channel records past the first chunk could name a channel that earlier
        # chunks of the run use: read chunk by chunk then, as a lone chunk would be read.
        late = any(a >= first_end and not _known(op, buf, a, *known) for op, a, _ in gaps.tables)
        if reason or late:
            for rec, _c, _ln, indexes, ents, lo, hi, _job in run:
                self._records(rec, mem[lo:hi], ents, indexes)
            return
        for op, a, b in gaps.tables:
            k = int(np.searchsorted(ends, a, side="right"))
            self.record_table(op, buf, a, b, run[k][0])
        self._from_index(buf, joined, gaps.record_lengths)

    def _from_matched(self, run: list[_Queued], matched: list[_Matched], mem: np.ndarray) -> None:
        """Add the wanted messages of chunks whose index the C walk found right (the same
        result as :meth:`_read_run`'s numpy check and :meth:`_from_index`)."""
        if any(m.tables for m in matched):
            known = set(self.tables.channels), set(self.tables.schemas)
            # as in _read_run: a new Schema/Channel past the first chunk -> chunk by chunk
            # (read again from the file: the walk kept only the wanted payloads)
            if any(
                not _known(op, content, 0, *known) for m in matched[1:] for op, content in m.tables
            ):
                for rec, c, ln, indexes, *_ in run:
                    self.chunk(rec, c, ln, indexes)
                return
            for item, m in zip(run, matched, strict=True):
                for op, content in m.tables:
                    self.record_table(op, content, 0, len(content), item[0])
        per: dict[int, list[tuple[_Matched, int]]] = {}
        for m in matched:
            for g, (cid, e, _row) in enumerate(m.groups):
                if len(e):
                    per.setdefault(cid, []).append((m, g))
        for cid, parts in per.items():
            spans = np.array([m.spans[g] for m, g in parts])
            counts = [len(m.groups[g][1]) for m, g in parts]
            lo, hi = int(spans[:, 0].min()), int(spans[:, 1].max())
            self.tables.seen_span(cid, sum(counts), lo, hi)
            b = self.builder(cid)
            if b is None:
                continue
            rows = [m.out[m.groups[g][2] :][:k] for (m, g), k in zip(parts, counts, strict=True)]
            times = [r[:, 1] for r in rows]
            log_time = times[0] if len(times) == 1 else np.concatenate(times)
            if self.times_only:
                z = np.zeros(len(log_time), np.int64)
                b.add(mem[:0], z, z, log_time, copy=False)
                continue
            width = int(spans[0, 2]) - 22
            if width > 0 and (spans[:, 2:4] == width + 22).all():
                # one payload length (a pose topic): each chunk's rows lie end to end
                blocks = [(int(at), k) for at, k in zip(spans[:, 4], counts, strict=True)]
                b.take_blocks(mem, blocks, width, log_time)
                continue
            recs = rows[0] if len(rows) == 1 else np.concatenate(rows)
            b.add(mem, recs[:, 0], recs[:, 2] - 22, log_time)

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


def _known(op: int, b: Buffer, at: int, channels: set[int], schemas: set[int]) -> bool:
    """Whether the Schema/Channel record whose content starts at ``at`` has an id already
    known (a repeat, as writers put them in chunks); an unreadable id counts as unknown."""
    if at + 2 > len(b):
        return False
    (i,) = U16.unpack_from(b, at)
    return i in (channels if op == OP_CHANNEL else schemas)
