"""MCAP record layouts that need no numpy: magic, opcodes, strings, Schema and Channel
records, the footer's summary offset. Shared by the reader (:mod:`uwval.io.mcap_chunk`,
:mod:`uwval.io.mcap_raw`) and by the read begun before numpy loads (:mod:`uwval.io.mcap_runs`),
so that both parse a log alike. Every parser is bounds-checked: damaged bytes raise
:class:`ValueError` or :class:`struct.error`, or give a reason string."""

from __future__ import annotations

import struct
from typing import Any

MAGIC = b"\x89MCAP0\r\n"
OP_HEADER, OP_FOOTER, OP_SCHEMA, OP_CHANNEL, OP_MESSAGE, OP_CHUNK = 1, 2, 3, 4, 5, 6
OP_MESSAGE_INDEX, OP_CHUNK_INDEX, OP_STATISTICS, OP_DATA_END = 7, 8, 11, 15
OP_METADATA, OP_METADATA_INDEX, OP_SUMMARY_OFFSET = 0x0C, 0x0D, 0x0E

REC = struct.Struct("<BQ")
U16 = struct.Struct("<H")
U32 = struct.Struct("<I")
U64 = struct.Struct("<Q")

#: bytes, memoryview, mmap or a uint8 ndarray: whatever struct reads and slicing copies
#: (typeshed's ReadableBuffer cannot be sliced, and numpy's stubs do not make arrays one).
Buffer = Any


def string_at(b: Buffer, pos: int, end: int) -> tuple[str, int]:
    """A u32-length-prefixed UTF-8 string at ``pos`` that must end by ``end``."""
    (n,) = U32.unpack_from(b, pos)
    if pos + 4 + n > end:
        raise ValueError(f"a string of {n} bytes at byte {pos} runs past its record")
    # text that is not UTF-8 is damage (the mcap library refuses it too): ValueError
    return bytes(b[pos + 4 : pos + 4 + n]).decode("utf-8"), pos + 4 + n


def parse_schema(b: Buffer, pos: int, end: int) -> tuple[int, str, str, str]:
    """(id, name, encoding, text) of the Schema record whose content is ``b[pos:end]``."""
    (sid,) = U16.unpack_from(b, pos)
    name, p = string_at(b, pos + 2, end)
    enc, p = string_at(b, p, end)
    text, _ = string_at(b, p, end)
    return sid, name, enc, text


def parse_channel(b: Buffer, pos: int, end: int) -> tuple[int, int, str, str]:
    """(id, schema id, topic, message encoding) of the Channel record whose content is
    ``b[pos:end]``."""
    cid, sid = struct.unpack_from("<HH", b, pos)
    topic, p = string_at(b, pos + 4, end)
    enc, _ = string_at(b, p, end)
    return cid, sid, topic, enc


def summary_start(b: Buffer, size: int) -> tuple[int, str]:
    """Where the summary section of the MCAP file ``b`` (``size`` bytes) starts: (offset,
    "") when its footer points at one that passes its CRC; (0, "") when the file has none
    (no footer: the writer did not finish; or a footer without summary); (0, what is wrong)
    when the footer's offset or the section's CRC is damaged."""
    from uwval.io.crc import crc32

    if size < 8 + 29 + 8 or b[size - 8 : size] != MAGIC:
        return 0, ""
    op, ln = REC.unpack_from(b, size - 8 - 29)
    if op != OP_FOOTER or ln != 20:
        return 0, ""
    start, _offs, crc = struct.unpack_from("<QQI", b, size - 8 - 20)
    if start == 0:
        return 0, ""
    if start < 8 or start > size - 8 - 29:
        return (
            0,
            f"the footer's summary offset {start} is outside the file; read without the summary",
        )
    if crc and crc32(b[start : size - 8 - 4]) != crc:
        return 0, f"the summary section (byte {start}) fails its CRC check; read without it"
    return start, ""
