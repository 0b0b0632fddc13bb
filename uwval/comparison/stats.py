"""Error statistics: per-axis metrics, evo-named norm statistics, Pearson r with p and CI.

Pure numpy plus ``math`` (no scipy at import or run time: the compare command's start-up
must stay lean). The Pearson p-value uses the exact null distribution of r (a Beta law,
as scipy.stats.pearsonr does) through a continued-fraction incomplete beta function; the
95 % confidence interval uses Fisher's z transform (scipy's default method).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import NDArray

F64 = NDArray[np.float64]

#: Two-sided 95 % quantile of the standard normal distribution.
Z_975 = 1.959963984540054


def order_statistics(values: F64, ranks: set[int], *, overwrite: bool = False) -> dict[int, float]:
    """The values at 0-based ``ranks`` of ``values`` sorted ascending (no NaN in ``values``).

    Ranks are taken from the highest down, each by an in-place single-rank partition of the
    part below the previous one (numpy's SIMD select: one such partition costs ~1/10 of a
    partition at several ranks at once on 360,000 doubles); a rank just below the previous
    one is the maximum of what is left, swapped into place. ``values`` is left as it was,
    unless ``overwrite`` (a scratch float64 array: reordered in place, no copy).
    """
    part = np.asarray(values, dtype=np.float64) if overwrite else np.array(values, dtype=np.float64)
    out: dict[int, float] = {}
    hi = int(part.size)
    for r in sorted(ranks, reverse=True):
        below = part[:hi]
        if r == hi - 1:  # the largest of what is left: move it to r (what stays below is <=)
            k = int(below.argmax())
            below[k], below[r] = below[r], below[k]
        else:
            below.partition(r)
        out[r] = float(part[r])
        hi = r
    return out


def percentiles(values: F64, q: tuple[float, ...], *, overwrite: bool = False) -> list[float]:
    """``np.percentile(values, q)`` (method 'linear'), value for value, without its overheads.

    numpy's own percentile partitions at all ranks at once (slow path) and sends the ranks
    through ``np.unique``, which imports ``numpy.ma`` (~9 ms of a compare's start-up). This
    takes the same order statistics (:func:`order_statistics`) and the same interpolation
    arithmetic (numpy's ``_lerp``). ``values`` must be 1-D; a NaN anywhere gives NaN, as
    numpy does. ``values`` is left as it was unless ``overwrite`` (then it is reordered).
    """
    x = np.asarray(values, dtype=np.float64)
    n = int(x.size)
    if n == 0:
        raise ValueError("percentiles of an empty series")
    if not all(0.0 <= float(v) <= 100.0 for v in q):
        raise ValueError(f"percentiles must be in [0, 100], got {q}")
    if bool(np.isnan(x).any()):
        return [math.nan] * len(q)
    return _percentiles_no_nan(x, q, overwrite=overwrite)


def _percentiles_no_nan(x: F64, q: tuple[float, ...], *, overwrite: bool) -> list[float]:
    """:func:`percentiles` of a non-empty 1-D float64 series known to hold no NaN."""
    n = int(x.size)
    # numpy: q / 100 in float64, virtual index (n - 1) * q, neighbours floor and floor + 1
    # (both the last element, and gamma computed against index -1, at or past n - 1)
    virtual = [(n - 1) * (float(v) / 100.0) for v in q]
    below = [math.floor(v) if v < n - 1 else n - 1 for v in virtual]
    above = [b + 1 if v < n - 1 else n - 1 for b, v in zip(below, virtual, strict=True)]
    at = order_statistics(x, {*below, *above}, overwrite=overwrite)
    out = []
    for v, lo, hi in zip(virtual, below, above, strict=True):
        a, b = at[lo], at[hi]
        gamma = v - lo if v < n - 1 else v + 1.0
        diff = b - a
        out.append(b - diff * (1 - gamma) if gamma >= 0.5 else a + diff * gamma)
    return out


def median(values: F64) -> float:
    """``np.median(values)``, value for value (mean of the two middle values when n is even)."""
    x = np.asarray(values, dtype=np.float64)
    n = int(x.size)
    if n == 0:
        raise ValueError("median of an empty series")
    if bool(np.isnan(x).any()):
        return math.nan
    return _median_no_nan(x)


def _median_no_nan(x: F64) -> float:
    """:func:`median` of a non-empty 1-D float64 series known to hold no NaN."""
    n = int(x.size)
    h = n // 2
    if n % 2:
        return order_statistics(x, {h})[h]
    at = order_statistics(x, {h - 1, h})
    return (at[h - 1] + at[h]) / 2.0


def _std_given_mean(x: F64, mean: float, scratch: F64 | None = None) -> float:
    """``float(np.std(x))`` (ddof 0) given ``mean == float(np.mean(x))``, value for value:
    numpy's own steps (x - mean, squared in place, summed, / n, square root) without
    computing the mean again. ``scratch`` (x's shape) receives the deviations when given."""
    d = np.subtract(x, mean, out=scratch)
    np.multiply(d, d, out=d)
    return math.sqrt(float(d.sum()) / x.size)


def norm_stats(err: F64) -> dict[str, float]:
    """Statistics of a non-negative error series named and computed exactly as evo does.

    mean, median, std (population, ddof = 0), min, max, rmse = sqrt(mean(e^2)), sse = sum(e^2).
    Each value equals numpy's (np.mean, np.median, np.std...) to the bit; the sum of squares
    and the mean are computed once.
    """
    e = np.asarray(err, dtype=np.float64)
    if e.size == 0:
        return {k: math.nan for k in ("mean", "median", "std", "min", "max", "rmse", "sse")}
    mean = float(np.mean(e))
    # a NaN anywhere makes the mean NaN; otherwise the median needs no NaN scan
    med = median(e) if math.isnan(mean) else _median_no_nan(e)
    sq = np.multiply(e, e)  # np.power(e, 2), value for value
    sse = float(np.sum(sq))
    return {
        "mean": mean,
        "median": med,
        "std": _std_given_mean(e, mean, sq),
        "min": float(np.min(e)),
        "max": float(np.max(e)),
        "rmse": math.sqrt(sse / e.size),
        "sse": sse,
    }


def _betacf(a: float, b: float, x: float) -> float:
    """Continued fraction of the incomplete beta function (modified Lentz's method)."""
    tiny = 1e-300
    qab, qap, qam = a + b, a + 1.0, a - 1.0
    c, d = 1.0, 1.0 - qab * x / qap
    d = 1.0 / (d if abs(d) > tiny else tiny)
    h = d
    for m in range(1, 10_000):
        m2 = 2 * m
        aa = m * (b - m) * x / ((qam + m2) * (a + m2))
        d = 1.0 + aa * d
        d = 1.0 / (d if abs(d) > tiny else tiny)
        c = 1.0 + aa / c
        c = c if abs(c) > tiny else tiny
        h *= d * c
        aa = -(a + m) * (qab + m) * x / ((a + m2) * (qap + m2))
        d = 1.0 + aa * d
        d = 1.0 / (d if abs(d) > tiny else tiny)
        c = 1.0 + aa / c
        c = c if abs(c) > tiny else tiny
        delta = d * c
        h *= delta
        if abs(delta - 1.0) < 1e-15:
            break
    return h


def betainc_regularized(a: float, b: float, x: float) -> float:
    """Regularised incomplete beta I_x(a, b) for a, b > 0 and 0 <= x <= 1."""
    if x <= 0.0:
        return 0.0
    if x >= 1.0:
        return 1.0
    log_front = (
        math.lgamma(a + b) - math.lgamma(a) - math.lgamma(b) + a * math.log(x) + b * math.log1p(-x)
    )
    # the continued fraction is O(1) (>= 1e-3 here), so below exp(-800) the result underflows:
    # skip its ~sqrt(a) iterations (hundreds for the n = 360,000 series of a benchmark)
    if x < (a + 1.0) / (a + b + 2.0):
        return 0.0 if log_front < -800.0 else math.exp(log_front) * _betacf(a, b, x) / a
    if log_front < -800.0:
        return 1.0
    return 1.0 - math.exp(log_front) * _betacf(b, a, 1.0 - x) / b


#: Series whose standard deviation is below this (in their unit, m or deg) are constant.
CONSTANT_FLOOR = 1e-9


def pearson(a: F64, b: F64, *, overwrite_b: bool = False) -> dict[str, Any]:
    """Pearson r of two series with two-sided p-value and 95 % CI (Fisher z).

    Undefined (``r`` None with a ``reason``) for fewer than 3 samples or a constant series,
    instead of a division by zero. The p-value is P(|R| >= |r|) under independence, where R
    follows Beta(n/2 - 1, n/2 - 1) on [-1, 1] (identical to the t-test with n - 2 dof).
    ``pearson_ci`` treats the samples as independent (scipy's); ``pearson_ci_eff`` is the same
    interval from the effective sample size ``pearson_n_eff`` (:func:`effective_n`), the one
    to trust for autocorrelated series such as trajectories.
    ``overwrite_b``: ``b`` is a scratch float64 array, centred in place (one temporary less).
    """
    x = np.asarray(a, dtype=np.float64)
    y = np.asarray(b, dtype=np.float64)
    n = int(x.size)
    out: dict[str, Any] = {
        "pearson_r": None,
        "pearson_p": None,
        "pearson_ci": None,
        "pearson_n": n,
        "pearson_n_eff": None,
        "pearson_ci_eff": None,
        "pearson_reason": None,
    }
    if n < 3:
        out["pearson_reason"] = f"undefined: need at least 3 samples, got {n}"
        return out
    # a series is constant when its spread is at rounding level relative to its magnitude,
    # or below CONSTANT_FLOOR absolutely (1e-9 m or deg: quaternion round-off on an axis
    # that does not move gives ~1e-14 deg of noise, whose r would be meaningless)
    # max |v| as max(max v, -min v): the same value, no |v| temporary
    scale_x = max(float(x.max()), -float(x.min()), 1e-300)
    scale_y = max(float(y.max()), -float(y.min()), 1e-300)
    xm = x - x.mean()
    if overwrite_b and y is b and y.flags.writeable:
        ym = y
        ym -= y.mean()
    else:
        ym = y - y.mean()
    sxx = float(np.einsum("i,i->", xm, xm))
    syy = float(np.einsum("i,i->", ym, ym))
    const = [
        name
        for name, s2, sc in (("reference", sxx, scale_x), ("other", syy, scale_y))
        if math.sqrt(s2) <= max(1e-12 * sc, CONSTANT_FLOOR) * math.sqrt(n)
    ]
    if const:
        out["pearson_reason"] = f"undefined: {' and '.join(const)} series is constant"
        return out
    r = float(np.einsum("i,i->", xm, ym)) / (math.sqrt(sxx) * math.sqrt(syy))
    r = max(-1.0, min(1.0, r))
    ab = n / 2.0 - 1.0
    # two-sided: 2 * P(R <= -|r|) with (R + 1) / 2 ~ Beta(ab, ab)
    p = 2.0 * betainc_regularized(ab, ab, (1.0 - abs(r)) / 2.0) if abs(r) < 1.0 else 0.0
    out["pearson_r"] = r
    out["pearson_p"] = min(1.0, max(0.0, p))
    if n > 3 and abs(r) < 1.0:
        z = math.atanh(r)
        se = 1.0 / math.sqrt(n - 3)
        out["pearson_ci"] = [math.tanh(z - Z_975 * se), math.tanh(z + Z_975 * se)]
    elif abs(r) >= 1.0:
        out["pearson_ci"] = [r, r]
    n_eff = effective_n(xm, ym, sxx, syy)
    out["pearson_n_eff"] = n_eff
    out["pearson_ci_eff"] = fisher_ci(r, n_eff)
    return out


def effective_n(xm: F64, ym: F64, sxx: float, syy: float) -> float:
    """Effective sample size of a correlation between two autocorrelated series (Bartlett,
    AR(1) form): n (1 - rho_x rho_y) / (1 + rho_x rho_y), rho the lag-1 autocorrelations of
    the centred series ``xm``, ``ym`` (sums of squares ``sxx``, ``syy``); at most n. Two
    smooth trajectories (rho near 1) have few independent samples however densely sampled."""
    n = int(xm.size)
    if n < 3 or sxx <= 0.0 or syy <= 0.0:
        return float(n)
    # einsum, not np.dot: no BLAS threads woken for a vector product (uwval.cli.BLAS_THREADS)
    rho_x = float(np.einsum("i,i->", xm[1:], xm[:-1])) / sxx
    rho_y = float(np.einsum("i,i->", ym[1:], ym[:-1])) / syy
    prod = max(-0.999999, min(0.999999, rho_x * rho_y))
    return float(min(n, n * (1.0 - prod) / (1.0 + prod)))


def fisher_ci(r: float, n: float) -> list[float]:
    """95 % CI of a correlation ``r`` from ``n`` (effective) samples by Fisher's z; [-1, 1]
    when n <= 3 (too few independent samples to say anything), [r, r] when |r| = 1."""
    if abs(r) >= 1.0:
        return [r, r]
    if n <= 3.0:
        return [-1.0, 1.0]
    z = math.atanh(r)
    se = 1.0 / math.sqrt(n - 3.0)
    return [math.tanh(z - Z_975 * se), math.tanh(z + Z_975 * se)]


def axis_stats(
    signed_err: F64, reference: F64, other: F64, *, overwrite_other: bool = False
) -> dict[str, Any]:
    """Metrics of one axis: MAE, RMSE, max, p95 of |e|, bias (mean e), std of e, Pearson.

    ``signed_err`` is other - reference (angles already wrapped); ``reference`` and ``other``
    are the two series the correlation is computed on (``overwrite_other``: ``other`` is a
    scratch array the correlation may centre in place). Temporaries are freed as soon as
    they are used: on long streams, memory is a few series, not one per statistic.
    """
    e = np.asarray(signed_err, dtype=np.float64)
    if e.size == 0:
        stats: dict[str, Any] = {
            k: None for k in ("mae", "rmse", "max", "p95", "bias", "std", "median")
        }
        stats.update(pearson(e, e))
        return stats
    ae = np.abs(e)
    mae, ae_max = float(ae.mean()), float(ae.max())  # before the partition reorders ae
    if math.isnan(mae):  # a NaN somewhere (|e| >= 0: no inf - inf)
        p50 = p95 = math.nan
    else:
        p50, p95 = _percentiles_no_nan(ae, (50.0, 95.0), overwrite=True)
    bias = float(e.mean())
    stats = {
        "mae": mae,
        "rmse": math.sqrt(float(np.einsum("i,i->", e, e)) / e.size),
        "max": ae_max,
        "p95": float(p95),
        "median": float(p50),
        "bias": bias,
        "std": _std_given_mean(e, bias, ae),  # ae's memory is free again
    }
    del ae
    stats.update(pearson(reference, other, overwrite_b=overwrite_other))
    return stats
