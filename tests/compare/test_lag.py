"""The lag fitted from the poses alone (uwval.comparison.lag): closed forms, the block
bootstrap's coverage on autocorrelated errors, and the engine's ``lag`` JSON section."""

from __future__ import annotations

import math

import numpy as np
import pytest

from uwval.comparison import compare
from uwval.comparison.lag import (
    block_length,
    bootstrap_lag_ci,
    fit_lag,
    lag_least_squares,
    lag_sentence,
)
from uwval.posestream import PoseStream

F = 50.0  # Hz


def _motion(t: np.ndarray) -> np.ndarray:
    """A vehicle path (m) whose velocity changes in every axis: closed-form positions."""
    return np.column_stack(
        [
            0.4 * np.sin(0.9 * t) + 0.1 * t,
            0.3 * np.cos(0.5 * t),
            0.05 * np.sin(1.7 * t + 0.3),
        ]
    )


def _angles(t: np.ndarray) -> np.ndarray:
    """Roll, pitch, yaw (deg) of the same vehicle, small and smooth."""
    return np.column_stack([3 * np.sin(0.7 * t), 2 * np.sin(0.4 * t + 1.0), 20 * np.sin(0.3 * t)])


def test_least_squares_lag_of_an_exact_linear_error_is_exact() -> None:
    rng = np.random.default_rng(0)
    v = rng.normal(size=(500, 3))
    assert lag_least_squares(v, -0.0124 * v) == pytest.approx(0.0124, rel=1e-12)
    # closed form -sum(v.e)/sum(v.v) on a one-column case
    v1 = np.array([1.0, 2.0, -1.0])
    e1 = np.array([-0.01, -0.03, 0.02])
    assert lag_least_squares(v1, e1) == pytest.approx(-(-0.01 - 0.06 - 0.02) / 6.0)


def test_fit_recovers_a_pure_delay_of_a_closed_form_motion() -> None:
    lag = 0.0124
    t = np.arange(0, 30, 1 / F)
    ref, late = _motion(t), _motion(t - lag)
    rpy_err = _angles(t - lag) - _angles(t)
    fit = fit_lag(t, ref, late, _angles(t), rpy_err, seed=1)
    assert fit is not None
    # the linearisation error is O(lag^2 * acceleration): well below 1 %
    assert fit.fitted_s == pytest.approx(lag, rel=0.01)
    assert fit.rotation_fitted_s == pytest.approx(lag, rel=0.01)
    assert fit.ci95_s[0] <= fit.fitted_s <= fit.ci95_s[1]
    assert fit.explained > 0.999
    raw_x = float(np.abs(late[:, 0] - ref[:, 0]).mean())
    assert fit.raw_mae["x"] == pytest.approx(raw_x)
    assert fit.residual["x"].mae < 0.02 * raw_x
    # mean speed per axis from the closed-form derivative of x
    vx = 0.4 * 0.9 * np.cos(0.9 * t) + 0.1
    assert fit.speed["x"] == pytest.approx(float(np.abs(vx).mean()), rel=1e-3)


def test_a_unity_ahead_of_gazebo_gives_a_negative_lag_and_says_early() -> None:
    t = np.arange(0, 20, 1 / F)
    fit = fit_lag(t, _motion(t), _motion(t + 0.02), seed=0)
    assert fit is not None
    assert fit.fitted_s == pytest.approx(-0.02, rel=0.01)
    assert "early" in lag_sentence(fit)


def test_an_error_that_is_not_a_lag_is_not_called_one() -> None:
    """Noise much larger than any lag the motion could show: the sentence says the error is
    not mostly a lag before it names the best-fitting one."""
    t = np.arange(0, 20, 1 / F)
    ref = _motion(t)
    noisy = _motion(t - 0.01) + np.random.default_rng(3).normal(0, 0.5, ref.shape)
    fit = fit_lag(t, ref, noisy, seed=0)
    assert fit is not None
    assert fit.explained < 0.5
    text = lag_sentence(fit)
    assert text.startswith("The error is not mostly a lag")
    assert "Unity shows Gazebo's pose" not in text
    # a clean delay keeps the plain answer
    clean = fit_lag(t, ref, _motion(t - 0.01), seed=0)
    assert clean is not None
    assert lag_sentence(clean).startswith("Unity shows Gazebo's pose 10.0 ms late")


def test_no_motion_no_lag() -> None:
    t = np.arange(0, 5, 1 / F)
    still = np.zeros((t.size, 3))
    assert fit_lag(t, still, still + 0.001) is None


def _ar1(rng: np.random.Generator, n: int, phi: float, sd: float) -> np.ndarray:
    """An AR(1) series x_k = phi x_{k-1} + eps (stationary, marginal std ``sd``)."""
    eps = rng.normal(0.0, sd * math.sqrt(1 - phi * phi), n)
    x = np.empty(n)
    x[0] = rng.normal(0.0, sd)
    for k in range(1, n):  # a small test series: the recursion is the definition
        x[k] = phi * x[k - 1] + eps[k]
    return x


def test_block_bootstrap_covers_the_lag_when_the_ages_are_autocorrelated() -> None:
    """Per-sample ages following an AR(1) (phi 0.95) around the true lag: the 95 % CI must
    cover the true lag in about 95 % of seeded trials; an iid bootstrap (block 1) would be
    far too narrow (its coverage is checked to be lower, so the test can tell them apart)."""
    n, lag, trials = 1500, 0.0124, 60
    t = np.arange(n) / F
    v = np.column_stack([np.cos(0.8 * t), np.sin(0.5 * t), 0.3 * np.cos(1.3 * t)])
    covered_block = covered_iid = 0
    for seed in range(trials):
        rng = np.random.default_rng(seed)
        age = lag + _ar1(rng, n, 0.95, 0.004)
        e = -age[:, None] * v
        fitted = lag_least_squares(v, e)
        block = block_length(np.einsum("ij,ij->i", v, e + fitted * v))
        lo, hi = bootstrap_lag_ci(v, e, block=block, seed=seed)
        covered_block += lo <= lag <= hi
        lo1, hi1 = bootstrap_lag_ci(v, e, block=1, seed=seed)
        covered_iid += lo1 <= lag <= hi1
    assert covered_block / trials >= 0.85
    assert covered_iid / trials < 0.7


def test_bootstrap_is_seeded() -> None:
    t = np.arange(0, 10, 1 / F)
    rng = np.random.default_rng(3)
    ref = _motion(t)
    oth = _motion(t - 0.01) + rng.normal(0, 1e-4, ref.shape)
    a = fit_lag(t, ref, oth, seed=7)
    b = fit_lag(t, ref, oth, seed=7)
    assert a is not None
    assert b is not None
    assert a.ci95_s == b.ci95_s


def _stream(t: np.ndarray, pos: np.ndarray, *, applied: np.ndarray | None = None) -> PoseStream:
    q = np.tile([0.0, 0.0, 0.0, 1.0], (t.size, 1))
    return PoseStream.from_arrays(
        np.round(t * 1e9).astype(np.int64),
        pos,
        q,
        frame="enu",
        applied_stamp=None if applied is None else np.round(applied * 1e9).astype(np.int64),
    )


def test_engine_reports_the_lag_section_and_the_measured_latency() -> None:
    """A sample-and-hold renderer at 60 Hz showing each frame the pose of 15 ms earlier:
    compare's ``lag`` section fits it, and the applied stamps measure the same figure."""
    tg = np.arange(0, 20, 1 / F)
    tu = np.arange(0.1, 19.9, 1 / 60)
    shown = tu - 0.015
    ref = _stream(tg, _motion(tg))
    other = _stream(tu, _motion(shown), applied=shown)
    res = compare(ref, other)
    lag = res.to_json()["lag"]
    assert lag["fitted_s"] == pytest.approx(0.015, abs=0.0005)
    assert lag["ci95_s"][0] <= lag["measured_s"] <= lag["ci95_s"][1]
    assert lag["measured_mean_s"] == pytest.approx(0.015, abs=1e-6)
    assert lag["agrees"] is True
    assert res.lag is not None
    assert lag["residual"]["x"]["mae"] < 0.1 * res.stats["axes"]["x"]["mae"]
    assert lag["sentence"].startswith("Unity shows Gazebo's pose 15.")
    assert "the two agree" in lag["sentence"]


def test_engine_lag_can_be_switched_off() -> None:
    tg = np.arange(0, 5, 1 / F)
    res = compare(_stream(tg, _motion(tg)), _stream(tg, _motion(tg - 0.01)), lag=False)
    assert res.to_json()["lag"] is None


@pytest.mark.parametrize("df", [5, 10, 14, 30, 200])
def test_t_quantile_matches_scipy(df: int) -> None:
    from scipy import stats

    from uwval.comparison.lag import t_quantile_975

    tol = 0.01 if df < 10 else 0.002
    assert t_quantile_975(df) == pytest.approx(float(stats.t.ppf(0.975, df)), rel=tol)


def test_engine_says_why_there_is_no_lag() -> None:
    tg = np.arange(0, 5, 1 / F)
    still = np.zeros((tg.size, 3))
    doc = compare(_stream(tg, still), _stream(tg, still + 0.001)).to_json()
    assert doc["lag"] is None
    assert "does not move enough" in doc["lag_reason"]
