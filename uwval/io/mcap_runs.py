"""Runs of MCAP chunks read in C, and such a read begun before numpy loads.

:mod:`uwval.io.mcap_raw` reads a log's chunks by calls of ``_mcapwalk.scan_chunks`` (zstd and
the CRC from C, on POSIX threads, the GIL released; one call reads run after run, the calling
thread planning the next run, from its chunk headers and indexes, while its threads decompress
this one, and returns once :data:`SCAN_HOLD_BYTES` of results are held). This module holds what
that needs and does not need numpy: whether the C reader is there (:func:`scan_ready`), the
per-id table the call is given (:func:`scan_maps`), and the early start (:func:`start_scan`):
``uwval compare`` of one MCAP file begins the same calls on another thread while numpy and the
comparison code load (:mod:`uwval.io.early`), and the read takes their results
(:func:`take_started`) only when it would make exactly the same calls: the same file,
unchanged, the same first chunk, summary start, channel table and budgets. Anything else, or
any doubt while starting, starts nothing; a started read that is not taken is dropped.
"""

from __future__ import annotations

import mmap
import os
from collections.abc import Iterable, Mapping
from typing import Any

from uwval.io.mcap_records import (
    MAGIC,
    OP_CHANNEL,
    OP_CHUNK,
    OP_HEADER,
    OP_SCHEMA,
    REC,
    parse_channel,
    parse_schema,
    summary_start,
)

#: file bytes a run reads at most (their map pages are dropped from RSS by the next run)
SCAN_FILE_BYTES = 8 << 20
#: the early read's runs are smaller: it runs while numpy loads, and the two add up in RSS
#: (the image log's whole-command peak against the log without images, read from disk, each
#: run planning the next: 4 MB +5.3 %, 3 MB +2.4 %, 2 MB +0.6 % and 2 % slower than 3 MB)
EARLY_FILE_BYTES = 2 << 20
#: decompressed bytes of the chunks holding a wanted channel that a run reads at most
#: (their wanted payloads go to the threads' arenas, then packed per channel)
SCAN_SLOT_BYTES = 8 << 20
#: the rows and payloads one in-process call holds at most before it returns (the reader adds
#: them to its topics, then calls again: the results' memory is reused, not grown)
SCAN_HOLD_BYTES = 8 << 20
#: larger chunks (or a damaged size field claiming more) are never read by the C runs
MAX_CHUNK = 64 << 20
#: scan_chunks' reasons to stop (see _mcapwalk.c): the run is full (the next run goes on),
#: the chunk at next_pos is for the batched path (damaged, odd, new tables, too large), or
#: of a kind the C call never reads (the rest of the file then goes to the batched path)
SCAN_BUDGET, SCAN_CHUNK, SCAN_OTHER = 2, 3, 4

#: one run's result: (stop, next_pos, chunks read, rows, packed payloads, per channel); the
#: three buffers are ``_mcapwalk.Held`` objects (the C call's memory, read-only, no copy)
ScanResult = tuple[int, int, int, Any, Any, Any]

_codecs: list[bool] = []


def accelerator() -> Any:
    """The C module (``uwval.io._mcapwalk``) when built and ``UWVAL_NO_ACCELERATOR`` is not
    set; else None."""
    if os.environ.get("UWVAL_NO_ACCELERATOR"):
        return None
    try:
        from uwval.io import _mcapwalk
    except ImportError:  # pragma: no cover - installs without a C compiler
        return None
    return _mcapwalk


def scan_ready() -> bool:
    """Whether the C run reader is on (see :func:`accelerator`) and found libzstd and a
    CRC-32 (asked once per process)."""
    if accelerator() is None:
        return False
    if not _codecs:
        mod = accelerator()
        lib = None
        try:
            import isal.isal_zlib

            lib = isal.isal_zlib.__file__
        except ImportError:  # pragma: no cover - isal is a dependency
            pass
        # (built without POSIX threads and dlopen, the module has no run reader)
        ready = mod is not None and hasattr(mod, "setup_codecs") and mod.setup_codecs(lib)
        _codecs.append(bool(ready))
    return _codecs[0]


def scan_maps(channels: Mapping[int, str], schemas: Iterable[int], want: set[str] | None) -> bytes:
    """The table ``scan_chunks`` is given, one byte per id: 1 the channel is wanted or not
    known yet (a Channel record in its chunk may name it), 2 a known channel, 4 a known
    schema. ``channels``: id -> normalised topic; ``want``: normalised topics (None: all)."""
    m = bytearray(b"\x01" * 65536)
    for cid, topic in channels.items():
        m[cid] = 3 if want is None or topic in want else 2
    for sid in schemas:
        m[sid] |= 4
    return bytes(m)


# ---------------------------------------------------------------------------- early start
def _table(
    op: int, b: mmap.mmap, c: int, end: int, channels: dict[int, str], schemas: set[int]
) -> None:
    """A Schema or Channel record, taken as uwval.io.mcap_chunk.Tables.record takes it (the
    same parsers; any damage raises: nothing is started then)."""
    from uwval.io.names import norm_topic

    if op == OP_SCHEMA:
        schemas.add(parse_schema(b, c, end)[0])
    else:
        cid, _sid, topic, _enc = parse_channel(b, c, end)
        channels.setdefault(cid, norm_topic(topic))


def plan_early(mm: mmap.mmap, want: set[str]) -> tuple[int, int, bytes] | None:
    """(first chunk, summary start, channel table) of a log whose summary is sound and whose
    data section begins with nothing but its Header and Schema/Channel records; None for
    anything else (the read then does it all itself)."""
    size = len(mm)
    start, _damage = summary_start(mm, size)
    if not start or mm[:8] != MAGIC:
        return None
    channels: dict[int, str] = {}
    schemas: set[int] = set()
    pos, end = start, size - 8 - 29
    while pos + 9 <= end:
        op, ln = REC.unpack_from(mm, pos)
        if pos + 9 + ln > end:
            return None
        if op in (OP_SCHEMA, OP_CHANNEL):
            _table(op, mm, pos + 9, pos + 9 + ln, channels, schemas)
        pos += 9 + ln
    pos = 8
    while pos + 9 <= start:
        op, ln = REC.unpack_from(mm, pos)
        if op == OP_CHUNK:
            return pos, start, scan_maps(channels, schemas, want)
        if op not in (OP_HEADER, OP_SCHEMA, OP_CHANNEL) or pos + 9 + ln > start:
            return None
        if op != OP_HEADER:
            _table(op, mm, pos + 9, pos + 9 + ln, channels, schemas)
        pos += 9 + ln
    return None


def _read_runs(mm: mmap.mmap, plan: tuple[int, int, bytes], threads: int) -> list[ScanResult]:
    """Every run of the plan, by one ``scan_chunks`` call: the thread needs the GIL only to
    start and end (between calls it would wait for the importing thread each time)."""
    pos, end, maps = plan
    mod = accelerator()
    out: tuple[list[ScanResult], int] = mod.scan_chunks(
        mod.scan_workspace(True),  # the main thread drops the results: page-mapped
        mm,
        pos,
        end,
        maps,
        EARLY_FILE_BYTES,
        SCAN_SLOT_BYTES,
        threads,
        True,
        MAX_CHUNK,
        0,
        0,
        True,
    )
    return out[0]
