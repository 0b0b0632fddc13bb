"""Type stub of the optional C accelerator of the pose decoder (see _posedecode.c)."""

from typing import Any

import numpy as np
from numpy.typing import NDArray

def decode_uniform(
    rows: Any,
    width: int,
    ranges: NDArray[np.int64],
    stamp_at: int,
    pose_at: int,
    stamp: NDArray[np.int64],
    position: NDArray[np.float64],
    orientation: NDArray[np.float64],
    /,
) -> int:
    """-1 when every row of ``width`` bytes holds row 0's bytes in each (at, length) range
    (stamps and poses then filled); else the first row that differs."""
