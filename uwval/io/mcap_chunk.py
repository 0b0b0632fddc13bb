"""MCAP records at the chunk level: record layouts, decompression, record walks, and the
check of a chunk's MessageIndex against the records it points at (used by
:mod:`uwval.io.mcap_raw`). Every parser here is bounds-checked: damaged bytes give a reason
string or a :class:`ValueError`, never a wrong offset.
"""

from __future__ import annotations

import itertools
import struct
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from uwval.errors import LogReadError
from uwval.io.mcap_records import (
    OP_CHANNEL,
    OP_MESSAGE,
    OP_SCHEMA,
    REC,
    U64,
    Buffer,
    parse_channel,
    parse_schema,
    string_at,
)
from uwval.io.ros import normalize_type_name

_CHUNK = struct.Struct("<QQQI")
_MSG = struct.Struct("<HIQQ")


@dataclass
class Channel:
    """An MCAP channel: id, topic, message encoding, schema id."""

    id: int
    topic: str
    encoding: str
    schema_id: int


@dataclass
class Tables:
    """Schemas and channels seen so far, and per-channel message counts and log-time spans."""

    schemas: dict[int, tuple[str, str, str]] = field(default_factory=dict)  # name, enc, text
    channels: dict[int, Channel] = field(default_factory=dict)
    counts: dict[int, int] = field(default_factory=dict)
    times: dict[int, list[int]] = field(default_factory=dict)  # cid -> [min, max]

    def record(self, op: int, b: Buffer, pos: int, end: int) -> None:
        """Parse a Schema or Channel record whose content is ``b[pos:end]``."""
        if op == OP_SCHEMA:
            sid, name, enc, text = parse_schema(b, pos, end)
            self.schemas[sid] = (name, enc, text)
        elif op == OP_CHANNEL:
            cid, sid, topic, enc = parse_channel(b, pos, end)
            self.channels.setdefault(cid, Channel(cid, topic, enc, sid))

    def msgtype(self, ch: Channel) -> tuple[str, str, str]:
        """(normalised type, 'cdr'|'ros1'|other encoding, definition text) of a channel."""
        name, _senc, text = self.schemas.get(ch.schema_id, ("", "", ""))
        enc = {"cdr": "cdr", "ros1": "ros1"}.get(ch.encoding, ch.encoding)
        return normalize_type_name(name) if name else "", enc, text

    def seen_span(self, cid: int, count: int, lo: int, hi: int) -> None:
        """Count ``count`` (> 0) messages of channel ``cid`` logged between ``lo`` and ``hi``
        (ns) inclusive."""
        self.counts[cid] = self.counts.get(cid, 0) + count
        cur = self.times.setdefault(cid, [lo, hi])
        cur[0], cur[1] = min(cur[0], lo), max(cur[1], hi)

    def seen(self, cid: int, times: NDArray[np.int64]) -> None:
        """Count messages of channel ``cid`` logged at ``times`` (ns)."""
        if times.size == 0:
            return
        self.counts[cid] = self.counts.get(cid, 0) + int(times.size)
        lo, hi = int(times.min()), int(times.max())
        cur = self.times.setdefault(cid, [lo, hi])
        cur[0], cur[1] = min(cur[0], lo), max(cur[1], hi)


@dataclass(frozen=True)
class ChunkHeader:
    """A Chunk record's fields; the compressed records are ``data_len`` bytes at ``data_at``."""

    usize: int
    crc: int
    compression: str
    data_at: int
    data_len: int


def parse_chunk_header(b: Buffer, c: int, end: int, *, partial: bool = False) -> ChunkHeader:
    """The header of the Chunk record whose content starts at ``c`` and ends at ``end``.

    ``partial``: the record is cut off at ``end`` (the data may be shorter than declared).
    """
    if c + 28 + 4 > end:
        raise ValueError("chunk header is cut off")
    _start, _stop, usize, crc = _CHUNK.unpack_from(b, c)
    comp, p = string_at(b, c + 28, end)
    if p + 8 > end:
        raise ValueError("chunk header is cut off")
    (rlen,) = U64.unpack_from(b, p)
    if not partial and p + 8 + rlen != end:
        raise ValueError(f"records length {rlen} does not match the chunk record")
    if usize > 1 << 34:
        raise ValueError(f"uncompressed size {usize} is implausible")
    return ChunkHeader(usize, crc, comp, p + 8, min(rlen, end - p - 8))


def decompress(comp: str, b: Buffer, at: int, n: int, usize: int) -> bytes:
    """A chunk's records, decompressed; :class:`LogReadError` when that fails."""
    data = memoryview(b)[at : at + n]
    try:
        if comp == "":
            return bytes(data)
        if comp == "zstd":
            import zstandard

            return zstandard.ZstdDecompressor().decompress(data, max_output_size=usize)
        if comp == "lz4":
            import lz4.frame

            return bytes(lz4.frame.decompress(data))
    except Exception as exc:  # zstd / lz4 raise their own types for damaged streams
        raise LogReadError(
            f"cannot be decompressed ({comp}: {' '.join(str(exc).split())})"
        ) from exc
    finally:
        data.release()
    raise LogReadError(f"unsupported chunk compression {comp!r}")


def decompress_prefix(comp: str, b: Buffer, at: int, end: int) -> bytes:
    """As much of a cut-off chunk's records as its compressed prefix ``b[at:end]`` yields."""
    raw = bytes(b[at:end])
    try:
        if comp == "":
            return raw
        if comp == "zstd":
            import zstandard

            return bytes(zstandard.ZstdDecompressor().decompressobj().decompress(raw))
        if comp == "lz4":
            import lz4.frame

            return bytes(lz4.frame.LZ4FrameDecompressor().decompress(raw))
    except Exception as exc:
        raise LogReadError(f"cannot decompress the cut chunk: {exc}") from exc
    raise LogReadError(f"unsupported chunk compression {comp!r}")


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
    """Walk the records in ``data[start:end]`` (slow path: one Python step per record)."""
    out = WalkResult(stop=start)
    q = start
    while q < end:
        if q + 9 > end:
            out.reason = "record header cut off"
            break
        op, rl = REC.unpack_from(data, q)
        cc = q + 9
        if cc + rl > end or op == 0:
            out.reason = f"record of opcode {op} and {rl} bytes does not fit"
            break
        if op == OP_MESSAGE:
            if rl < 22:
                out.reason = f"Message record of {rl} bytes is too short"
                break
            cid, _seq, lt, _pub = _MSG.unpack_from(data, cc)
            m = out.messages.setdefault(cid, ([], [], []))
            m[0].append(cc + 22)
            m[1].append(rl - 22)
            m[2].append(lt)
        elif op in (OP_SCHEMA, OP_CHANNEL):
            out.tables.append((op, cc, cc + rl))
        q = cc + rl
    out.stop = q
    return out


def unaligned(buf: NDArray[np.uint8], dtype: str) -> NDArray[Any]:
    """A read-only view of ``buf`` whose element i is the ``dtype`` value starting at byte i
    (so ``view[offsets]`` gathers fields of records at arbitrary, unaligned offsets)."""
    itemsize = np.dtype(dtype).itemsize
    n = max(int(buf.shape[0]) - itemsize + 1, 0)
    view: NDArray[Any] = np.ndarray((n,), dtype=dtype, buffer=buf, strides=(1,))
    view.flags.writeable = False
    return view


def check_index(
    buf: NDArray[np.uint8],
    ents: dict[int, NDArray[np.uint64]],
    *,
    limit: NDArray[np.int64] | None = None,
    cuts: NDArray[np.int64] | None = None,
) -> tuple[str, WalkResult]:
    """Check a chunk's MessageIndex against its decompressed records.

    Every entry must point at a Message record of its channel with the entry's log time,
    lying inside the chunk; the indexed records must not overlap, and the bytes between them
    must hold only non-Message records (no message left out of the index). Returns
    ``("", walk of the gaps)`` when the index is right, else ``(reason, _)``; the reason
    names the first channel (in index order) whose entries fail.

    All channels' entries are checked together (one gather of the 23-byte record heads per
    chunk, not one per channel: a chunk of an interleaved log holds every topic).

    Several chunks can be checked at once (:mod:`uwval.io.mcap_raw` batches them: the per-call
    cost, not the bytes, dominates small chunks): ``buf`` is then their records end to end,
    the entries' offsets are into ``buf``, ``limit`` is each entry's own chunk end in ``buf``
    (in ``ents``' order, channel by channel) and ``cuts`` the chunk boundaries: no record may
    cross one, and the bytes between indexed records are walked chunk by chunk.
    """
    size = int(buf.shape[0])
    gaps = WalkResult()
    items = [(cid, e) for cid, e in ents.items() if len(e)]
    if not items:
        return "the index lists no messages", gaps
    counts = np.array([len(e) for _, e in items], dtype=np.int64)
    bounds = np.concatenate(([0], np.cumsum(counts)))
    allE = items[0][1] if len(items) == 1 else np.concatenate([e for _, e in items])

    def first(mask: NDArray[np.bool_]) -> int:
        """The channel of the first flagged entry."""
        k = int(np.searchsorted(bounds, int(np.argmax(mask)), side="right")) - 1
        return items[k][0]

    rec_u = allE[:, 1]
    if limit is None:
        out = rec_u > np.uint64(size - 31) if size >= 31 else np.ones(len(rec_u), dtype=bool)
    else:
        out = (limit < 31) | (rec_u > (np.maximum(limit, 31) - 31).astype(np.uint64))
    if out.any():
        return f"channel {first(out)}: an entry points outside the chunk", gaps
    rec = rec_u.astype(np.int64)
    # the record heads' fields, each one gather through an unaligned view (rec + 23 <= size)
    u64 = unaligned(buf, "<u8")
    op = buf[rec]
    rl = u64[rec + 1]
    ch = unaligned(buf, "<u2")[rec + 9]
    lt = u64[rec + 15]
    cid_of = np.repeat(np.array([c for c, _ in items], dtype=np.int64), counts)
    checks = (
        (op != OP_MESSAGE, "an entry does not point at a Message record"),
        (ch != cid_of, "an entry points at a message of another channel"),
        (lt != allE[:, 0], "an entry's log time differs from its message's"),
        ((rl < 22) | (rl > size), "a Message record has an impossible length"),
    )
    bad = checks[0][0] | checks[1][0] | checks[2][0] | checks[3][0]
    if bad.any():
        k = int(np.searchsorted(bounds, int(np.argmax(bad)), side="right")) - 1
        lo, hi = int(bounds[k]), int(bounds[k + 1])
        what = next(text for mask, text in checks if mask[lo:hi].any())
        return f"channel {items[k][0]}: {what}", gaps
    rl64 = rl.astype(np.int64)
    stop = rec + 9 + rl64
    past = stop > (size if limit is None else limit)
    if past.any():
        return f"channel {first(past)}: a Message record runs past the chunk", gaps
    for k, (cid, _e) in enumerate(items):
        gaps.record_lengths[cid] = rl64[int(bounds[k]) : int(bounds[k + 1])]
    order = np.argsort(rec, kind="stable")
    s, t = rec[order], stop[order]
    if (s[1:] < t[:-1]).any():
        return "indexed records overlap", gaps
    holes = np.flatnonzero(s[1:] > t[:-1])
    spans = [(0, int(s[0]))] + [(int(t[i]), int(s[i + 1])) for i in holes] + [(int(t[-1]), size)]
    if cuts is not None and cuts.size:
        spans = _split_spans(spans, cuts)
    for a, b in spans:
        if a == b:
            continue
        w = walk_records(buf, a, b)
        if w.stop != b:
            return f"bytes {a}..{b} between indexed records are not whole records", gaps
        if w.messages:
            n = sum(len(m[2]) for m in w.messages.values())
            return f"{n} message(s) at bytes {a}..{b} are missing from the index", gaps
        gaps.tables.extend(w.tables)
    return "", gaps


def _split_spans(spans: list[tuple[int, int]], cuts: NDArray[np.int64]) -> list[tuple[int, int]]:
    """``spans`` (sorted byte ranges) split at the chunk boundaries ``cuts`` (sorted) inside
    them: records are walked chunk by chunk, never across a boundary."""
    out: list[tuple[int, int]] = []
    for a, b in spans:
        inner = cuts[(cuts > a) & (cuts < b)] if b - a > 0 else cuts[:0]
        edges = [a, *(int(x) for x in inner), b]
        out.extend(itertools.pairwise(edges))
    return out
