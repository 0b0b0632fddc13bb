"""Type stub of the optional C accelerator of the TUM reader (see _tumparse.c)."""

import numpy as np
from numpy.typing import NDArray

def parse_block(
    src: bytes | bytearray | memoryview,
    stamps: NDArray[np.float64],
    pose: NDArray[np.float64],
    final: bool,
    /,
) -> tuple[int, int]:
    """Parse complete TUM lines of ``src`` into float64 ``stamps`` and ``pose`` (7 a row).

    Returns (rows written, bytes used); ValueError names the byte offset of a bad line.
    """
