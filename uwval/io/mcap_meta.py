"""MCAP metadata records found through a log's summary: the footer, the summary offsets and
the metadata index (a few small reads, no scan of the data section and no mcap reader)."""

from __future__ import annotations

import struct
from pathlib import Path

from uwval.io.mcap_records import (
    MAGIC,
    OP_FOOTER,
    OP_METADATA,
    OP_METADATA_INDEX,
    OP_SUMMARY_OFFSET,
    string_at,
)


def summary_metadata(path: str | Path, name: str) -> list[dict[str, str]] | None:
    """The key/value maps of the MCAP metadata records called ``name``, in the order of the
    log's summary (as mcap's ``iter_metadata`` yields them), read through the footer, the
    summary offsets and the metadata index (MCAP spec: records are opcode u8, length u64,
    body): a few small reads instead of importing and running mcap's reader. None when the
    log has no summary (the caller then scans it); a damaged one raises."""
    with open(path, "rb") as fh:
        fh.seek(0, 2)
        size = fh.tell()
        tail_len = 1 + 8 + 20 + len(MAGIC)
        if size < len(MAGIC) + tail_len:
            return None
        fh.seek(size - tail_len)
        tail = fh.read(tail_len)
        if tail[-8:] != MAGIC or tail[0] != OP_FOOTER:
            return None
        length, summary_start, offsets_start, _crc = struct.unpack_from("<QQQI", tail, 1)
        if length != 20 or summary_start == 0:
            return None
        footer_at = size - tail_len

        def read(start: int, end: int) -> bytes:
            if not 0 < start <= end <= footer_at:
                raise ValueError("summary section outside the file")
            fh.seek(start)
            return fh.read(end - start)

        def records(buf: bytes) -> list[tuple[int, bytes]]:
            out, pos = [], 0
            while pos < len(buf):
                op, n = struct.unpack_from("<BQ", buf, pos)
                end = pos + 9 + n
                if end > len(buf):
                    raise ValueError("record past the end of its section")
                out.append((op, buf[pos + 9 : end]))
                pos = end
            return out

        # the metadata index group, through the summary offsets when there are some
        section = (summary_start, offsets_start or footer_at)
        if offsets_start:
            for op, body in records(read(offsets_start, footer_at)):
                if op == OP_SUMMARY_OFFSET and body[0] == OP_METADATA_INDEX:
                    start, n = struct.unpack_from("<QQ", body, 1)
                    section = (start, start + n)
                    break
            else:
                return []  # no metadata index group: the log has no metadata
        found = []
        for op, body in records(read(*section)):
            if op != OP_METADATA_INDEX:
                continue
            offset, n = struct.unpack_from("<QQ", body, 0)
            if string_at(body, 16, len(body))[0] != name:
                continue
            rec = read(offset, offset + n)
            op_rec, n_rec = struct.unpack_from("<BQ", rec, 0)
            if op_rec != OP_METADATA or 9 + n_rec > len(rec):
                raise ValueError("metadata index points at no metadata record")
            body_rec = rec[9 : 9 + n_rec]
            rec_name, pos = string_at(body_rec, 0, len(body_rec))
            (map_len,) = struct.unpack_from("<I", body_rec, pos)
            pos += 4
            end = pos + map_len
            if rec_name != name or end > len(body_rec):
                raise ValueError("damaged metadata record")
            values: dict[str, str] = {}
            while pos < end:
                key, pos = string_at(body_rec, pos, end)
                values[key], pos = string_at(body_rec, pos, end)
            found.append(values)
        return found
