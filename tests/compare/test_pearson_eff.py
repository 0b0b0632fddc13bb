"""Pearson r's autocorrelation-aware CI (effective sample size) on synthetic AR(1) series."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.signal import lfilter

from uwval.comparison.stats import effective_n, fisher_ci, pearson


def _ar1(rng: np.random.Generator, n: int, phi: float) -> np.ndarray:
    """A stationary AR(1) series x_k = phi x_{k-1} + eps_k with unit marginal variance."""
    eps = rng.normal(0.0, math.sqrt(1 - phi * phi), n)
    eps[0] = rng.normal()
    return np.asarray(lfilter([1.0], [1.0, -phi], eps))


def test_effective_n_of_two_ar1_series_matches_bartlett() -> None:
    """Two independent AR(1) series with phi 0.9 each: n_eff = n (1 - phi^2) / (1 + phi^2)."""
    rng = np.random.default_rng(0)
    n, phi = 200_000, 0.9
    x, y = _ar1(rng, n, phi), _ar1(rng, n, phi)
    xm, ym = x - x.mean(), y - y.mean()
    got = effective_n(xm, ym, float(xm @ xm), float(ym @ ym))
    expected = n * (1 - phi * phi) / (1 + phi * phi)
    assert got == pytest.approx(expected, rel=0.03)
    # white noise: every sample counts
    w, v = rng.normal(size=n), rng.normal(size=n)
    wm, vm = w - w.mean(), v - v.mean()
    assert effective_n(wm, vm, float(wm @ wm), float(vm @ vm)) == pytest.approx(n, rel=0.02)


def test_effective_n_ci_covers_zero_for_independent_autocorrelated_series() -> None:
    """Independent AR(1) pairs (true r = 0): the effective-n CI covers 0 in ~95 % of seeded
    trials; the textbook CI, which counts every sample, in far fewer."""
    rng = np.random.default_rng(1)
    trials, n, phi = 400, 400, 0.9
    eff = iid = 0
    for _ in range(trials):
        out = pearson(_ar1(rng, n, phi), _ar1(rng, n, phi))
        lo, hi = out["pearson_ci_eff"]
        eff += lo <= 0.0 <= hi
        lo, hi = out["pearson_ci"]
        iid += lo <= 0.0 <= hi
    assert 0.9 <= eff / trials <= 0.99
    assert iid / trials < 0.7


def test_fisher_ci_closed_form_and_its_limits() -> None:
    r, n = 0.5, 28.0
    lo, hi = fisher_ci(r, n)
    z, se = math.atanh(0.5), 1 / 5.0
    assert lo == pytest.approx(math.tanh(z - 1.959963984540054 * se))
    assert hi == pytest.approx(math.tanh(z + 1.959963984540054 * se))
    assert fisher_ci(0.99, 3.0) == [-1.0, 1.0]  # no independent sample left: no information
    assert fisher_ci(1.0, 100.0) == [1.0, 1.0]


def test_smooth_trajectories_have_few_independent_samples() -> None:
    """Two smooth 4 s trajectories sampled at 50 Hz: r is near 1, and the CI from the
    effective sample size is far wider than the textbook one."""
    t = np.arange(0, 4, 0.02)
    a = np.sin(0.8 * t)
    b = np.sin(0.8 * (t - 0.0124))
    out = pearson(a, b)
    assert out["pearson_r"] > 0.999
    assert out["pearson_n_eff"] < 0.05 * out["pearson_n"]
    width_eff = out["pearson_ci_eff"][1] - out["pearson_ci_eff"][0]
    width = out["pearson_ci"][1] - out["pearson_ci"][0]
    assert width_eff > 10 * width
