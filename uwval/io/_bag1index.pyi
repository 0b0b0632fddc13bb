"""Type stub of the optional C accelerator of the ROS 1 reader (see _bag1index.c)."""

from typing import Any

import numpy as np
from numpy.typing import NDArray

def locate(records: Any, conn: int, entries: NDArray[np.uint32], out: NDArray[np.int64], /) -> bool:
    """Check IndexData entries (sec, nsec, offset) of ``conn`` against the chunk's records.

    True: each points at a MessageData record of ``conn`` with its time, data inside the
    chunk; ``out`` then holds (data start, data length) per entry.
    """
