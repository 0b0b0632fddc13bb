"""MCAP metadata records found through a log's summary: the footer, the summary offsets and
the metadata index, parsed by mcap's record readers (a few small reads, no scan of the data
section)."""

from __future__ import annotations

import io
from pathlib import Path

from mcap.records import Footer, Metadata, MetadataIndex, SummaryOffset
from mcap.stream_reader import StreamReader

from uwval.io.mcap_raw import MAGIC


def summary_metadata(path: str | Path, name: str) -> list[dict[str, str]] | None:
    """The key/value maps of the MCAP metadata records called ``name``, in the order of the
    log's summary (as mcap's ``iter_metadata`` yields them), read through the footer, the
    summary offsets and the metadata index. None when the log has no summary (the caller
    then scans it); a damaged one raises."""
    with open(path, "rb") as fh:
        size = fh.seek(0, 2)
        if size < 8 + 29 + 8:
            return None
        fh.seek(size - 37)
        tail = fh.read(37)
        if tail[-8:] != MAGIC or tail[0] != 2:
            return None
        footer = next(iter(StreamReader(io.BytesIO(tail), skip_magic=True).records))
        if not isinstance(footer, Footer) or footer.summary_start == 0:
            return None
        if not 0 < footer.summary_start <= size - 37:
            raise ValueError("summary section outside the file")

        def records(start: int, end: int) -> list[object]:
            if not 0 < start <= end <= size - 37:
                raise ValueError("summary section outside the file")
            fh.seek(start)
            body = fh.read(end - start) + tail  # a footer ends the stream
            return list(StreamReader(io.BytesIO(body), skip_magic=True).records)

        section = (footer.summary_start, footer.summary_offset_start or size - 37)
        if footer.summary_offset_start:
            groups = records(footer.summary_offset_start, size - 37)
            found = [g for g in groups if isinstance(g, SummaryOffset) and g.group_opcode == 0x0D]
            if not found:
                return []  # no metadata index group: the log has no metadata
            section = (found[0].group_start, found[0].group_start + found[0].group_length)
        out = []
        for idx in records(*section):
            if isinstance(idx, MetadataIndex) and idx.name == name:
                rec = records(idx.offset, idx.offset + idx.length)[0]
                if not isinstance(rec, Metadata) or rec.name != name:
                    raise ValueError("the metadata index points at no metadata record")
                out.append(dict(rec.metadata))
        return out
