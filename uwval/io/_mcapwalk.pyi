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
