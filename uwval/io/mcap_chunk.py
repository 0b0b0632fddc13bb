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
from uwval.io.raw import Buffer

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
    rec: NDArray[np.int64] = field(default_factory=lambda: np.zeros(0, np.int64))
    length: NDArray[np.int64] = field(default_factory=lambda: np.zeros(0, np.int64))


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


#: a Message record's head, packed: 23 bytes (one gather of them checks every field)
_HEAD = np.dtype([("op", "u1"), ("len", "<u8"), ("cid", "<u2"), ("seq", "<u4"), ("time", "<u8")])


def check_index(
    buf: NDArray[np.uint8],
    rows: NDArray[np.uint64],
    chunk: NDArray[np.intp],
    groups: list[tuple[int, int, int]],
    at: NDArray[np.int64],
) -> tuple[str, WalkResult]:
    """Check the MessageIndex entries of chunks lying end to end in ``buf`` (chunk k in
    ``buf[at[k]:at[k + 1]]``): ``rows[lo:hi]`` are channel ``cid``'s (log time, record
    offset in its chunk) for each ``(cid, lo, hi)`` of ``groups``; ``chunk[i]``: row i's.

    Every entry must point at a Message record of its channel with the entry's log time,
    inside its chunk; the indexed records must not overlap, and the bytes between them must
    hold only other records (no message left out of the index). Returns ``("", walk)`` when
    the index is right (the gaps' records; each row's record start and length in rec, length),
    else ``(reason, _)`` naming the first channel that fails. One gather checks every head.
    """
    out = WalkResult()
    if not len(rows):
        return "the index lists no messages", out

    def first(mask: NDArray[np.bool_]) -> int:
        return groups[int(np.searchsorted([g[1] for g in groups], np.argmax(mask), "right")) - 1][0]

    base, limit = at[chunk], at[chunk + 1]
    room = limit - base - 31  # the last offset a Message record's head fits at
    off = rows[:, 1]
    bad = (room < 0) | (off > np.maximum(room, 0).astype(np.uint64))
    if bad.any():
        return f"channel {first(bad)}: an entry points outside the chunk", out
    rec = off.astype(np.int64) + base
    heads = np.ndarray((buf.shape[0] - 22,), "V23", buf, strides=(1,))[rec].view(_HEAD)
    rl = heads["len"]
    cids = np.repeat([c for c, _l, _h in groups], [h - lo for _c, lo, h in groups])
    checks = (
        (heads["op"] != Opcode.MESSAGE, "an entry does not point at a Message record"),
        (heads["cid"] != cids, "an entry points at a message of another channel"),
        (heads["time"] != rows[:, 0], "an entry's log time differs from its message's"),
        (
            (rl < 22) | (rl > (limit - rec - 9).astype(np.uint64)),
            "a Message record runs past its chunk",
        ),
    )
    for mask, text in checks:
        if mask.any():
            return f"channel {first(mask)}: {text}", out
    rl = rl.astype(np.int64)
    # records in file order: one sort of packed (start, length) keys; argsort only for a run
    # of 4 GiB or more (argsort alone raised a 1 h log's peak RSS from ~200 to ~250 MiB)
    if buf.shape[0] < 1 << 32:
        key = np.sort((rec.astype(np.uint64) << 32) | rl.astype(np.uint64), kind="stable")
        s = (key >> 32).astype(np.int64)
        t = s + 9 + (key & 0xFFFFFFFF).astype(np.int64)
    else:
        order = np.argsort(rec, kind="stable")
        s, t = rec[order], (rec + 9 + rl)[order]
    if (s[1:] < t[:-1]).any():
        return "indexed records overlap", out
    holes = np.flatnonzero(s[1:] > t[:-1])
    spans = [(0, int(s[0]))] + [(int(t[i]), int(s[i + 1])) for i in holes]
    cuts = at[1:-1]
    for a, b in [*spans, (int(t[-1]), int(buf.shape[0]))]:
        edges = [a, *(int(x) for x in cuts[(cuts > a) & (cuts < b)]), b]
        for lo, hi in itertools.pairwise(edges):  # walked chunk by chunk
            w = walk_records(buf, lo, hi)
            if w.stop != hi:
                return f"bytes {lo}..{hi} between indexed records are not whole records", out
            if w.messages:
                n = sum(len(m[2]) for m in w.messages.values())
                return f"{n} message(s) at bytes {lo}..{hi} are missing from the index", out
            out.tables.extend(w.tables)
    out.rec, out.length = rec, rl
    return "", out
