"""CRC-32 (IEEE 802.3, zlib's polynomial: MCAP's chunk and section checksums).

Checking every chunk is a pass over all decompressed bytes (400 MB for a 10-minute log with a
camera topic): zlib's CRC took 100 ms of CPU on it, ISA-L's (``isal``, a dependency) 15 ms, a
fifth of that log's whole compare. Both compute the same function (tests/io/test_crc.py);
zlib is the fallback where no ``isal`` wheel exists.
"""

from __future__ import annotations

try:
    from isal.isal_zlib import crc32 as crc32

    BACKEND = "isal"
except ImportError:  # pragma: no cover - isal is a dependency; kept for odd platforms
    from zlib import crc32 as crc32

    BACKEND = "zlib"
