"""Stamps: int64 nanoseconds <-> float64 seconds, exactly (shared by every reader and by
:mod:`uwval.comparison.sync`; no format's parser needs to be imported for them).

uwval keeps stamps as int64 ns; text formats (TUM, CSV) and evo's association speak float
seconds. Both conversions are the correctly rounded ones, so a stamp parsed from text and
converted back gives the very double that was parsed.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

F64 = NDArray[np.float64]
I64 = NDArray[np.int64]

#: Nanoseconds per second.
NS_PER_S = 1_000_000_000


def ns_from_seconds(seconds: ArrayLike) -> I64:
    """Float seconds -> int64 ns, splitting off the whole seconds exactly first.

    ``s - floor(s)`` is exact for doubles, so the only rounding is of the fraction times 1e9
    (error < 1e-6 ns); the result is the integer nanosecond nearest to the double itself.
    """
    s = np.asarray(seconds, dtype=np.float64)
    whole = np.floor(s)
    frac_ns = np.rint((s - whole) * 1e9).astype(np.int64)
    return np.asarray(whole.astype(np.int64) * NS_PER_S + frac_ns)


def seconds_from_ns(t: ArrayLike) -> F64:
    """Int64 ns -> float seconds, the double nearest to ``t / 1e9`` (whole part added last).

    For stamps parsed by :func:`ns_from_seconds` this returns exactly the parsed double, so
    evo-style float comparisons on seconds see the same numbers evo sees.
    """
    t = np.asarray(t, dtype=np.int64)
    # below 2^53 ns (104 days) the int is an exact double: one correctly rounded division
    small = np.abs(t) < (1 << 53)
    if small.all():
        return np.asarray(t.astype(np.float64) / 1e9)
    whole, frac = np.divmod(t, NS_PER_S)
    out = whole.astype(np.float64) + frac.astype(np.float64) / 1e9
    if small.any():
        out[small] = t[small].astype(np.float64) / 1e9
    return np.asarray(out)
