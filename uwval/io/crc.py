"""CRC-32 (IEEE 802.3, zlib's polynomial: MCAP's chunk and section checksums).

Checking every chunk of a log is a pass over all its decompressed bytes (400 MB for a
10-minute log with a camera topic). Measured on 400 MB (2026-11-27, shared 2-core machine):
zlib's table-driven CRC 100 ms of CPU, ISA-L's (``isal``, a dependency; carry-less
multiplies) 15 ms: a fifth of that log's whole compare, so the dependency stays.
Both compute the same function (tests/test_crc.py holds them equal); zlib is the fallback
where no ``isal`` wheel exists.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

crc32: Callable[[Any], int]
try:
    from isal.isal_zlib import crc32 as _isal_crc32

    def crc32(data: Any) -> int:
        """CRC-32 of a bytes-like object (ISA-L)."""
        return int(_isal_crc32(data))

    BACKEND = "isal"
except ImportError:  # pragma: no cover - isal is a dependency; kept for odd platforms
    from zlib import crc32 as _zlib_crc32

    def crc32(data: Any) -> int:
        """CRC-32 of a bytes-like object (zlib)."""
        return _zlib_crc32(data)

    BACKEND = "zlib"
