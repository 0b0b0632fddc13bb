"""MCAP metadata records found through a log's summary: the footer, the summary offsets and
the metadata index, parsed by mcap's record readers (a few small reads, no scan of the data
section, and not mcap's whole reader)."""

from __future__ import annotations

import io
import struct
from pathlib import Path

from mcap.opcode import Opcode
from mcap.records import Metadata, MetadataIndex, SummaryOffset
from mcap.stream_reader import StreamReader

from uwval.io.mcap_raw import MAGIC


def summary_metadata(path: str | Path, name: str) -> list[dict[str, str]] | None:
    """The key/value maps of the MCAP metadata records called ``name``, in the order of the
    log's summary (as mcap's ``iter_metadata`` yields them). None when the log has no
    summary (the caller then scans it); a damaged one raises."""
    with open(path, "rb") as fh:
        size = fh.seek(0, 2)
        fh.seek(max(size - 37, 0))
        tail = fh.read(37)  # the footer record and the closing magic
        if size < 45 or tail[-8:] != MAGIC or tail[0] != Opcode.FOOTER:
            return None
        start, offsets = struct.unpack_from("<QQ", tail, 9)

        def records(lo: int, hi: int) -> list[object]:
            """The records in bytes lo..hi (the footer after them ends the stream)."""
            if not 0 < lo <= hi <= size - 37:
                raise ValueError(f"{path}: summary section outside the file")
            fh.seek(lo)
            return list(StreamReader(io.BytesIO(fh.read(hi - lo) + tail), skip_magic=True).records)

        if not start:
            return None
        group = (start, offsets or size - 37)
        if offsets:  # straight to the metadata index group
            found = [
                r
                for r in records(offsets, size - 37)
                if isinstance(r, SummaryOffset) and r.group_opcode == Opcode.METADATA_INDEX
            ]
            if not found:
                return []  # no metadata index group: the log has no metadata
            group = (found[0].group_start, found[0].group_start + found[0].group_length)
        out = []
        for idx in records(*group):
            if isinstance(idx, MetadataIndex) and idx.name == name:
                rec = records(idx.offset, idx.offset + idx.length)[0]
                if not isinstance(rec, Metadata) or rec.name != name:
                    raise ValueError(f"{path}: the metadata index points at no metadata record")
                out.append(dict(rec.metadata))
        return out
