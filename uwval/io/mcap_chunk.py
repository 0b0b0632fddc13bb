"""MCAP chunks (used by :mod:`uwval.io.mcap_raw`): the Chunk record's header, its records
decompressed into place and checked against the CRC, the check of its MessageIndex against
the records it points at, and the record walk used when they disagree. Every parser here is
bounds-checked: damaged bytes give a reason string or a :class:`ValueError`, never a wrong
offset.
"""

from __future__ import annotations

import itertools
import mmap
import struct
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from mcap.opcode import Opcode
from numpy.typing import NDArray

from uwval.io.crc import crc32
from uwval.io.raw import Buffer, unaligned

REC = struct.Struct("<BQ")  # every record: opcode, content length
_CHUNK = struct.Struct("<QQQI")  # message start/end time, uncompressed size, CRC
_MSG = struct.Struct("<HIQQ")  # channel id, sequence, log time, publish time
#: a declared uncompressed size above this is damage, never an allocation
MAX_CHUNK = 1 << 32


@dataclass(frozen=True)
class ChunkHeader:
    """A Chunk record's fields; the compressed records are ``data_len`` bytes at ``data_at``
    (offsets in the file)."""

    usize: int
    crc: int
    compression: str
    data_at: int
    data_len: int


def parse_chunk_header(b: Buffer, c: int, end: int, *, partial: bool = False) -> ChunkHeader:
    """The header of the Chunk record whose content is ``b[c:end]``; ``partial``: the record
    is cut off at ``end`` (its data may be shorter than declared)."""
    if c + 32 > end:
        raise ValueError("chunk header is cut off")
    _start, _stop, usize, crc = _CHUNK.unpack_from(b, c)
    (n,) = struct.unpack_from("<I", b, c + 28)
    p = c + 32 + n
    if p + 8 > end:
        raise ValueError("chunk header is cut off")
    comp = bytes(b[c + 32 : p]).decode("utf-8")
    (rlen,) = struct.unpack_from("<Q", b, p)
    if not partial and p + 8 + rlen != end:
        raise ValueError(f"records length {rlen} does not match the chunk record")
    if usize > MAX_CHUNK:
        raise ValueError(f"uncompressed size {usize} is implausible")
    if comp not in ("", "zstd", "lz4"):
        raise ValueError(f"unsupported compression {comp!r}")
    return ChunkHeader(usize, crc, comp, p + 8, min(rlen, end - p - 8))


def inflate_into(
    mm: mmap.mmap, hdr: ChunkHeader, dest: NDArray[np.uint8], zstd: Any
) -> tuple[str, str]:
    """Decompress a chunk's records from the file map ``mm`` into ``dest`` (exactly
    ``hdr.usize`` bytes) with the ``zstd`` decompressor (one per thread), check its CRC:
    ``("", "")``, or (what is wrong, drop cause). Runs on the inflate threads (zstd, lz4 and
    the CRC let the GIL go); the map's pages read leave the resident set at once (mapped
    pages of an image topic would count as this process's memory)."""
    import lz4.frame

    out = dest.data.cast("B")
    try:
        with memoryview(mm)[hdr.data_at : hdr.data_at + hdr.data_len] as src:
            if hdr.compression == "zstd":
                with zstd.stream_reader(src) as reader:
                    got = 0
                    while got < hdr.usize and (k := reader.readinto(out[got:])):
                        got += k
                    got += len(reader.read(1))
            else:
                data = lz4.frame.decompress(src) if hdr.compression else src
                if (got := len(data)) == hdr.usize:
                    out[:] = data
    except Exception as exc:  # zstd / lz4 raise their own types for damaged streams
        what = " ".join(str(exc).split())
        return f"cannot be decompressed ({hdr.compression}: {what})", "damaged_chunk"
    finally:
        lo, hi = -(-hdr.data_at // mmap.PAGESIZE) * mmap.PAGESIZE, hdr.data_at + hdr.data_len
        if hi - lo >= mmap.PAGESIZE and hasattr(mm, "madvise"):
            mm.madvise(mmap.MADV_DONTNEED, lo, (hi - lo) // mmap.PAGESIZE * mmap.PAGESIZE)
    if got != hdr.usize:
        return f"decompresses to another size than its header's {hdr.usize}", "damaged_chunk"
    if hdr.crc and crc32(out) != hdr.crc:
        return "fails its CRC check", "crc_mismatch"
    return "", ""


def decompress_prefix(comp: str, raw: bytes) -> bytes:
    """As much of a cut-off chunk's records as its compressed prefix ``raw`` yields."""
    if comp == "zstd":
        import zstandard

        return bytes(zstandard.ZstdDecompressor().decompressobj().decompress(raw))
    if comp == "lz4":
        import lz4.frame

        return bytes(lz4.frame.LZ4FrameDecompressor().decompress(raw))
    return raw


@dataclass
class WalkResult:
    """Records found by walking: per channel (payload offsets, lengths, log times), the
    Schema/Channel records as (op, content start, content end), and where the walk stopped
    (``stop`` < the end when a record is cut off or malformed, with ``reason``)."""

    messages: dict[int, tuple[list[int], list[int], list[int]]] = field(default_factory=dict)
    tables: list[tuple[int, int, int]] = field(default_factory=list)
    stop: int = 0
    reason: str = ""
    #: filled by :func:`check_index`: per channel, each indexed Message record's length
    record_lengths: dict[int, NDArray[np.int64]] = field(default_factory=dict)


def walk_records(data: Buffer, start: int, end: int) -> WalkResult:
    """Walk the records in ``data[start:end]`` one Python step each (a chunk whose index is
    missing or wrong); other records, private ones (0x80-0xFF) too, are stepped over."""
    out = WalkResult(stop=start)
    q = start
    while q < end:
        op, rl = REC.unpack_from(data, q) if q + 9 <= end else (0, 0)
        cc = q + 9
        if cc + rl > end or op == 0 or (op == Opcode.MESSAGE and rl < 22):
            out.reason = f"record of opcode {op} and {rl} bytes does not fit"
            break
        if op == Opcode.MESSAGE:
            cid, _seq, lt, _pub = _MSG.unpack_from(data, cc)
            m = out.messages.setdefault(cid, ([], [], []))
            m[0].append(cc + 22)
            m[1].append(rl - 22)
            m[2].append(lt)
        elif op in (Opcode.SCHEMA, Opcode.CHANNEL):
            out.tables.append((op, cc, cc + rl))
        q = cc + rl
    out.stop = q
    return out


def check_index(
    buf: NDArray[np.uint8],
    ents: dict[int, NDArray[np.uint64]],
    limit: NDArray[np.int64],
    cuts: NDArray[np.int64],
) -> tuple[str, WalkResult]:
    """Check the MessageIndex entries ``ents`` (per channel: (log time, record offset) rows,
    offsets into ``buf``) of chunks whose records lie end to end in ``buf``, split at
    ``cuts``; ``limit`` is each entry's own chunk end (in ``ents``' order).

    Every entry must point at a Message record of its channel with the entry's log time,
    inside its chunk; the indexed records must not overlap, and the bytes between them must
    hold only other records (no message left out of the index). Returns ``("", walk of the
    gaps)`` when the index is right, else ``(reason, _)`` naming the first channel that fails.
    All entries are checked by one gather of the record heads (a chunk holds every topic).
    """
    gaps = WalkResult()
    items = [(cid, e) for cid, e in ents.items() if len(e)]
    if not items:
        return "the index lists no messages", gaps
    counts = np.array([len(e) for _, e in items], dtype=np.int64)
    bounds = np.concatenate(([0], np.cumsum(counts)))
    every = np.concatenate([e for _, e in items])

    def first(mask: NDArray[np.bool_]) -> int:
        return items[int(np.searchsorted(bounds, int(np.argmax(mask)), side="right")) - 1][0]

    out = (limit < 31) | (every[:, 1] > (np.maximum(limit, 31) - 31).astype(np.uint64))
    if out.any():
        return f"channel {first(out)}: an entry points outside the chunk", gaps
    rec = every[:, 1].astype(np.int64)
    u64 = unaligned(buf, "<u8")
    rl = u64[rec + 1].astype(np.int64)
    checks = (
        (buf[rec] != Opcode.MESSAGE, "an entry does not point at a Message record"),
        (
            unaligned(buf, "<u2")[rec + 9] != np.repeat([c for c, _ in items], counts),
            "an entry points at a message of another channel",
        ),
        (u64[rec + 15] != every[:, 0], "an entry's log time differs from its message's"),
        ((rl < 22) | (rl > limit) | (rec + 9 + rl > limit), "a Message record runs past its chunk"),
    )
    for mask, text in checks:
        if mask.any():
            return f"channel {first(mask)}: {text}", gaps
    for k, (cid, _e) in enumerate(items):
        gaps.record_lengths[cid] = rl[int(bounds[k]) : int(bounds[k + 1])]
    order = np.argsort(rec, kind="stable")
    s, t = rec[order], (rec + 9 + rl)[order]
    if (s[1:] < t[:-1]).any():
        return "indexed records overlap", gaps
    holes = np.flatnonzero(s[1:] > t[:-1])
    spans = [(0, int(s[0]))] + [(int(t[i]), int(s[i + 1])) for i in holes]
    for a, b in [*spans, (int(t[-1]), int(buf.shape[0]))]:
        edges = [a, *(int(x) for x in cuts[(cuts > a) & (cuts < b)]), b]
        for lo, hi in itertools.pairwise(edges):  # walked chunk by chunk
            w = walk_records(buf, lo, hi)
            if w.stop != hi:
                return f"bytes {lo}..{hi} between indexed records are not whole records", gaps
            if w.messages:
                n = sum(len(m[2]) for m in w.messages.values())
                return f"{n} message(s) at bytes {lo}..{hi} are missing from the index", gaps
            gaps.tables.extend(w.tables)
    return "", gaps
