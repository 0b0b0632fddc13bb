"""The CRC used for MCAP integrity checks is zlib's CRC-32, whichever backend computes it."""

from __future__ import annotations

import zlib

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from uwval.io import crc


@given(st.binary(max_size=4096))
def test_crc32_equals_zlib(data: bytes) -> None:
    assert crc.crc32(data) == zlib.crc32(data)


def test_crc32_takes_buffers_as_zlib_does() -> None:
    rng = np.random.default_rng(7)
    arr = rng.integers(0, 256, size=1 << 20, dtype=np.uint8)
    raw = arr.tobytes()
    assert crc.crc32(memoryview(raw)[5:]) == zlib.crc32(raw[5:])
    assert crc.crc32(arr) == zlib.crc32(raw)


def test_the_fast_backend_is_installed() -> None:
    # isal is a dependency (pyproject): the zlib fallback is for platforms without a wheel
    assert crc.BACKEND == "isal"
