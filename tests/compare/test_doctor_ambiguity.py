"""Frame doctor on one-dimensional motion: ambiguous fits must not raise false alarms."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from uwval.comparison import doctor as doctor_module
from uwval.comparison.doctor import DOCTOR_SAMPLES, diagnose, thinning_step
from uwval.frames import convert_arrays


def _surge_only(n: int = 500) -> tuple[np.ndarray, np.ndarray]:
    t = np.linspace(0.0, 5.0, n)
    pos = np.stack([0.5 * t**2, np.zeros(n), np.zeros(n)], axis=1)
    quat = np.tile([0.0, 0.0, 0.0, 1.0], (n, 1))
    return pos, quat


def test_pure_surge_in_the_configured_frame_gives_no_warning() -> None:
    pos, quat = _surge_only()
    up, uq = convert_arrays(pos, quat, "enu", "unity-flu")
    d = diagnose(pos, quat, up, uq, configured="unity-flu")
    assert d.warning is None
    assert d.best == "unity-flu"


def test_pure_surge_in_the_wrong_frame_names_the_right_one() -> None:
    pos, quat = _surge_only()
    up, uq = convert_arrays(pos, quat, "enu", "unity-flu")
    d = diagnose(pos, quat, up, uq, configured="unity-enu")
    assert d.best == "unity-flu"
    assert d.warning is not None
    assert "unity-flu" in d.warning


def test_general_motion_still_identifies_each_convention() -> None:
    rng = np.random.default_rng(3)
    pos = np.cumsum(rng.normal(size=(400, 3)), axis=0)
    q = rng.normal(size=(400, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    for name in ("unity-flu", "unity-enu", "ned"):
        op, oq = convert_arrays(pos, q, "enu", name)
        d = diagnose(pos, q, op, oq, configured="enu")
        assert d.best == name
        assert d.warning is not None and name in d.warning


def test_pearson_undefined_for_round_off_noise_series() -> None:
    from uwval.comparison.stats import pearson

    rng = np.random.default_rng(0)
    noise = rng.normal(0.0, 1e-14, 500)  # a roll that does not move: quaternion round-off
    out = pearson(noise, rng.normal(0.0, 1e-14, 500))
    assert out["pearson_r"] is None
    assert "constant" in out["pearson_reason"]
    moving = np.linspace(0.0, 1e-6, 500)  # a micro-metre of real motion still counts
    assert pearson(moving, moving + rng.normal(0, 1e-9, 500))["pearson_r"] > 0.99


def test_index_or_slice_views_only_contiguous_runs() -> None:
    from uwval.comparison.sync import index_or_slice

    assert index_or_slice(np.arange(3, 9)) == slice(3, 9)
    for idx in ([0, 0, 2], [0, 2, 3], [5]):
        arr = np.asarray(idx, dtype=np.int64)
        sel = index_or_slice(arr)
        data = np.arange(10.0)
        np.testing.assert_array_equal(data[sel], data[arr])
    assert isinstance(index_or_slice(np.asarray([0, 0, 2])), np.ndarray)


@given(n=st.integers(0, 10**7), cap=st.integers(1, 10**5))
def test_thinning_keeps_at_most_cap_samples_and_as_many_as_it_can(n: int, cap: int) -> None:
    step = thinning_step(n, cap)
    kept = len(range(0, n, step))
    assert kept <= max(cap, 0) or n == 0
    assert step == 1 or len(range(0, n, step - 1)) > cap  # a smaller stride would keep too many


def test_a_long_stream_is_thinned_and_a_wrong_frame_is_still_named() -> None:
    """50,000 samples: scored on at most DOCTOR_SAMPLES of them, with the same verdicts and
    scores within 3 % of the scores over every sample (the sampling error is ~1 %)."""
    rng = np.random.default_rng(11)
    n = 50_000
    pos = np.cumsum(rng.normal(scale=0.01, size=(n, 3)), axis=0)
    q = np.cumsum(rng.normal(scale=0.01, size=(n, 4)), axis=0) + np.array([0.0, 0.0, 0.0, 3.0])
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    up, uq = convert_arrays(pos, q, "enu", "unity-flu")
    up = up + rng.normal(scale=0.002, size=up.shape)  # a realistic residual to score
    d = diagnose(pos, q, up, uq, configured="unity-enu")
    assert d.n_samples <= DOCTOR_SAMPLES < n
    assert d.best == "unity-flu" and d.warning is not None and "unity-flu" in d.warning
    ok = diagnose(pos, q, up, uq, configured="unity-flu")
    assert ok.warning is None and ok.best == "unity-flu"
    # the thinned RMS estimates the whole stream's: score every sample (cap = n) to compare
    full = doctor_module._scores(pos, q, up, uq)
    for name, sc in d.scores.items():
        assert sc["position_rms_m"] == pytest.approx(full[name]["position_rms_m"], rel=0.03)
        assert sc["rotation_rms_deg"] == pytest.approx(
            full[name]["rotation_rms_deg"], rel=0.03, abs=1e-9
        )


@given(seed=st.integers(0, 2**16), n=st.integers(3, 3000), noise=st.sampled_from([0.0, 1e-6, 0.3]))
@settings(max_examples=60, deadline=None)
def test_scores_equal_converting_every_sample_in_each_convention(
    seed: int, n: int, noise: float
) -> None:
    """The doctor's column-wise position sums and quaternion-only conversion give each
    convention's scores as converting the whole stream with convert_arrays does."""
    from uwval.frames import CONVENTIONS
    from uwval.rotations import geodesic_deg

    rng = np.random.default_rng(seed)
    pos = np.cumsum(rng.normal(size=(n, 3)), axis=0) + rng.normal(scale=100.0, size=3)
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    op, oq = convert_arrays(pos, q, "enu", str(rng.choice(list(CONVENTIONS))))
    op = op + rng.normal(scale=noise, size=op.shape)
    got = doctor_module._scores(pos, q, op, oq)
    assert list(got) == list(CONVENTIONS)
    for name in CONVENTIONS:
        p2, q2 = convert_arrays(op, oq, name, "enu")
        d = p2 - pos
        d -= d.mean(axis=0)
        want_pos = float(np.sqrt(np.sum(d * d) / n))
        want_rot = float(np.sqrt(np.mean(geodesic_deg(q2, q) ** 2)))
        assert got[name]["position_rms_m"] == pytest.approx(want_pos, rel=1e-9, abs=1e-12)
        assert got[name]["rotation_rms_deg"] == want_rot  # the same conversion, to the bit
