"""Type stub of the optional C accelerator of the MCAP reader (see _mcapwalk.c)."""

from typing import Any

import numpy as np
from numpy.typing import NDArray

def match_chunk(
    records: Any,
    base: int,
    groups: list[tuple[int, NDArray[np.uint64], int]],
    out: NDArray[np.int64],
    spans: NDArray[np.int64],
    tables: NDArray[np.int64],
    payload: NDArray[np.uint8] | None = None,
    payload_base: int = 0,
    /,
) -> tuple[int, int]:
    """Check a decompressed chunk against its index in one walk of its records.

    ``groups``: per indexed channel (id, (log time, offset) entries, first row in ``out`` or
    -1). Returns (code, Schema/Channel records found): code 0 = the index is right. With
    ``payload``, the wanted payloads are copied there (``out`` rows then give their place).
    """

def setup_codecs(crc_library: str | None, /) -> bool:
    """Find libzstd's decompressor and a CRC-32 (ISA-L's in ``crc_library``, else zlib's)
    for :func:`scan_chunks`; False when they are missing. Asked once per process."""

def crc32(data: Any, /) -> int:
    """The CRC-32 :func:`scan_chunks` checks chunks with (equal to ``zlib.crc32``)."""

class Held:
    """Bytes :func:`scan_chunks` read: a read-only buffer over its memory, freed with it."""

    def __buffer__(self, flags: int, /) -> memoryview: ...
    def __len__(self) -> int: ...

def scan_workspace(mapped: bool = False, /) -> object:
    """The buffers :func:`scan_chunks`' threads keep from call to call (one per reader);
    ``mapped``: its results are dropped by another thread (large ones then page-mapped)."""

def scan_chunks(
    workspace: object,
    mm: Any,
    pos: int,
    end: int,
    maps: bytes,
    file_budget: int,
    slot_budget: int,
    threads: int,
    payloads: bool,
    max_chunk: int,
    drop_from: int = 0,
    drop_to: int = 0,
    whole: bool = False,
    hold: int = 0,
    /,
) -> Any:
    """Read the run of chunks from byte ``pos`` (see _mcapwalk.c): (stop reason, where the
    reader goes on, chunks read, rows, packed payloads, per-channel table); with ``whole``,
    (the list of such tuples of the runs up to the first stop that is not the budget, or
    until ``hold`` bytes of results are held; where the last drop of map pages ended)."""
