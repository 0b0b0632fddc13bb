"""Compare engine on arrays: association, interpolation, statistics, alignment, offset, doctor."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from uwval.comparison import compare, diagnose, estimate_offset, norm_stats, pearson, umeyama
from uwval.comparison.stats import (
    axis_stats,
    betainc_regularized,
    median,
    order_statistics,
    percentiles,
)
from uwval.comparison.sync import interpolate_at, match_time_indices
from uwval.comparison.synthetic import unity_view, vehicle_motion
from uwval.errors import AlignmentError
from uwval.frames import convert_stream
from uwval.posestream import PoseStream
from uwval.rotations import quat_from_rpy


def _stream(
    t_s: np.ndarray, pos: np.ndarray, rpy: np.ndarray | None = None, frame: str = "enu"
) -> PoseStream:
    n = len(t_s)
    quat = quat_from_rpy(np.zeros((n, 3)) if rpy is None else rpy)
    return PoseStream.from_arrays(
        np.round(np.asarray(t_s) * 1e9).astype(np.int64), pos, quat, frame=frame, topic="t"
    )


# ------------------------------------------------------------------ evo's association


@settings(max_examples=60, deadline=None)
@given(
    st.lists(st.integers(0, 4000), min_size=1, max_size=60, unique=True),
    st.lists(st.integers(0, 4000), min_size=1, max_size=60, unique=True),
    st.sampled_from([0.0, 0.005, 0.01, 0.02]),
    st.sampled_from([0.0, 0.003, -0.007]),
    st.sampled_from([1, 3, 1 << 15]),
)
def test_match_time_indices_equals_evo(
    a: list[int], b: list[int], max_diff: float, offset: float, chunk: int
) -> None:
    from evo.core.sync import matching_time_indices

    import uwval.comparison.sync as sync_module

    s1 = 1305031102.0 + np.array(a, dtype=np.float64) * 0.001  # ms grid: exact ties happen
    s2 = 1305031102.0 + np.sort(np.array(b, dtype=np.float64)) * 0.001
    want1, want2 = matching_time_indices(s1, s2, max_diff, offset)
    saved = sync_module.MATCH_CHUNK
    sync_module.MATCH_CHUNK = chunk  # steps of 1 and 3 stamps: every chunk boundary
    try:
        got1, got2 = match_time_indices(s1, s2, max_diff, offset)
    finally:
        sync_module.MATCH_CHUNK = saved
    assert got1.tolist() == want1
    assert got2.tolist() == want2


def test_nearest_ties_go_to_earlier_sample_and_counts() -> None:
    ref = _stream(np.array([0.0, 1.0, 2.0, 3.0]), np.arange(12.0).reshape(4, 3))
    # other stamp 1.5 is exactly between ref 1 and 2: the earlier (1) wins, as in evo
    oth = _stream(np.array([0.5, 1.5, 9.0]), np.arange(9.0).reshape(3, 3))
    res = compare(ref, oth, sync="nearest", max_diff=0.5, min_samples=1)
    assert res.stats["sync"]["driving_stream"] == "other"
    assert res.stats["counts"] == {"matched": 2, "masked": 0, "dropped": 1}
    np.testing.assert_array_equal(res.reference.position[:, 0], [0.0, 3.0])


def test_no_overlap_is_a_clear_error() -> None:
    ref = _stream(np.arange(10.0), np.zeros((10, 3)))
    oth = _stream(np.arange(10.0) + 100.0, np.zeros((10, 3)))
    with pytest.raises(AlignmentError, match="no matching timestamps"):
        compare(ref, oth, sync="nearest")
    with pytest.raises(AlignmentError, match="only 0 aligned samples"):
        compare(ref, oth, sync="interp")


def test_too_few_samples_is_an_error() -> None:
    ref = _stream(np.arange(10.0), np.zeros((10, 3)))
    oth = _stream(np.array([8.5, 9.0, 20.0]), np.zeros((3, 3)))
    with pytest.raises(AlignmentError, match="need 5"):
        compare(ref, oth, min_samples=5)


# ------------------------------------------------------------------ interpolation


def test_interp_is_exact_on_linear_motion_and_never_extrapolates() -> None:
    t_ref = np.arange(0.0, 10.0, 0.1)
    ref = _stream(t_ref, np.column_stack([t_ref, 2 * t_ref, -t_ref]))
    t_oth = np.arange(1.05, 8.0, 0.25)
    oth = _stream(t_oth, np.column_stack([t_oth, 2 * t_oth, -t_oth]))
    res = compare(ref, oth)
    assert res.stats["counts"]["dropped"] == int(
        ((t_ref < 1.05 - 1e-9) | (t_ref > t_oth[-1] + 1e-9)).sum()
    )
    assert res.t[0] >= oth.t[0]
    assert res.t[-1] <= oth.t[-1]
    assert max(abs(res.errors[a]).max() for a in "xyz") < 1e-9


def test_interpolation_in_steps_equals_one_pass_and_takes_views() -> None:
    import uwval.comparison.sync as sync_module

    ref = vehicle_motion(3000, rate_hz=100.0, seed=4)
    oth = ref.with_(t=ref.t + np.int64(3_000_000), position=ref.position + 0.01)
    one_pass = interpolate_at(oth, ref.t)
    saved = sync_module.MATCH_CHUNK
    sync_module.MATCH_CHUNK = 7  # many steps, one boundary every 7 stamps
    try:
        stepped = interpolate_at(oth, ref.t)
    finally:
        sync_module.MATCH_CHUNK = saved
    for field in ("position", "orientation", "valid"):
        assert np.array_equal(getattr(stepped, field), getattr(one_pass, field)), field
    assert (stepped.outside, stepped.in_gap) == (one_pass.outside, one_pass.in_gap) == (1, 0)
    # the valid samples are one run (only the first reference stamp is outside): the aligned
    # reference rows are views of the stream, not copies
    res = compare(ref, oth)
    assert res.n_samples == 2999
    assert np.shares_memory(res.reference.position, ref.position)


def test_interp_slerp_halfway() -> None:
    t = np.array([0.0, 1.0])
    s = _stream(t, np.zeros((2, 3)), np.array([[0, 0, 0.0], [0, 0, math.pi / 2]]))
    out = interpolate_at(s, np.array([500_000_000], dtype=np.int64))
    assert out.valid.all()
    yaw = 2 * math.atan2(out.orientation[0, 2], out.orientation[0, 3])
    assert yaw == pytest.approx(math.pi / 4, abs=1e-12)


def test_gaps_longer_than_max_gap_are_masked_and_counted() -> None:
    t_oth = np.concatenate([np.arange(0.0, 5.0, 0.1), np.arange(7.0, 10.0, 0.1)])
    oth = _stream(t_oth, np.zeros((t_oth.size, 3)))
    t_ref = np.arange(0.0, 9.9, 0.02)
    ref = _stream(t_ref, np.zeros((t_ref.size, 3)))
    res = compare(ref, oth)  # default max gap: 5 nominal periods = 0.5 s < 2.1 s gap
    in_gap = int(((t_ref > 4.9 + 1e-9) & (t_ref < 7.0 - 1e-9)).sum())
    assert res.stats["counts"]["masked"] == in_gap
    assert res.stats["sync"]["max_gap_s"] == pytest.approx(0.5)
    assert any("masked" in w for w in res.warnings)
    res2 = compare(ref, oth, max_gap=3.0)
    assert res2.stats["counts"]["masked"] == 0


# ------------------------------------------------------------------ statistics


@settings(max_examples=200, deadline=None)
@given(
    st.lists(
        st.one_of(st.floats(-1e6, 1e6), st.sampled_from([0.0, 1.0, -1.0, 2.5])),
        min_size=1,
        max_size=40,
    ),
    st.lists(st.floats(0.0, 100.0), min_size=1, max_size=4),
)
def test_percentiles_and_median_equal_numpy_bit_for_bit(
    values: list[float], q: list[float]
) -> None:
    x = np.array(values)
    before = x.copy()
    got = percentiles(x, tuple(q))
    want = np.percentile(x, q)
    np.testing.assert_array_equal(got, want)  # exact (only -0.0 and 0.0 are "equal")
    assert median(x) == np.median(x)
    np.testing.assert_array_equal(x, before)  # the input is left as it was


@settings(max_examples=200, deadline=None)
@given(st.lists(st.integers(-5, 5), min_size=1, max_size=50), st.data())
def test_order_statistics_equal_the_sorted_values(values: list[int], data: st.DataObject) -> None:
    x = np.array(values, dtype=np.float64)
    ranks = data.draw(st.sets(st.integers(0, len(values) - 1), min_size=1))
    want = np.sort(x)
    assert order_statistics(x, ranks) == {r: want[r] for r in ranks}
    np.testing.assert_array_equal(x, np.array(values, dtype=np.float64))  # input untouched


def test_scratch_variants_give_the_same_numbers() -> None:
    # overwrite=True (percentiles) and overwrite_b=True (pearson) only save a temporary
    rng = np.random.default_rng(11)
    x, y = rng.normal(size=5001), rng.normal(size=5001)
    x_copy, y_copy = x.copy(), y.copy()
    assert percentiles(x_copy, (50.0, 95.0), overwrite=True) == percentiles(x, (50.0, 95.0))
    assert pearson(x, y_copy, overwrite_b=True) == pearson(x, y)
    assert np.allclose(y_copy, y - y.mean())  # y_copy was the scratch space
    err = y - x
    assert axis_stats(err, x, y.copy(), overwrite_other=True) == axis_stats(err, x, y)


def test_percentiles_on_a_large_series_and_with_nan() -> None:
    x = np.random.default_rng(5).lognormal(size=100_001)
    assert percentiles(x, (50.0, 95.0, 100.0, 0.0)) == list(np.percentile(x, [50, 95, 100, 0]))
    assert median(x[:-1]) == np.median(x[:-1])
    x[17] = np.nan
    assert all(math.isnan(v) for v in percentiles(x, (5.0, 95.0)))
    assert math.isnan(median(x))
    with pytest.raises(ValueError, match="empty"):
        percentiles(np.array([]), (50.0,))
    with pytest.raises(ValueError, match=r"\[0, 100\]"):
        percentiles(x, (101.0,))


def test_norm_stats_match_evo_definitions() -> None:
    e = np.array([3.0, 4.0, 0.0, 1.0])
    s = norm_stats(e)
    assert s["rmse"] == pytest.approx(math.sqrt(26 / 4))
    assert s["sse"] == 26.0
    assert s["std"] == pytest.approx(np.std(e))  # population
    assert (s["min"], s["max"], s["median"], s["mean"]) == (0.0, 4.0, 2.0, 2.0)


@settings(max_examples=40, deadline=None)
@given(st.integers(4, 300), st.floats(-0.99, 0.99), st.integers(0, 10_000))
def test_pearson_matches_scipy(n: int, rho: float, seed: int) -> None:
    from scipy import stats

    rng = np.random.default_rng(seed)
    x = rng.normal(size=n)
    y = rho * x + math.sqrt(1 - rho**2) * rng.normal(size=n)
    ours = pearson(x, y)
    ref = stats.pearsonr(x, y)
    assert ours["pearson_r"] == pytest.approx(ref.statistic, abs=1e-12)
    assert ours["pearson_p"] == pytest.approx(ref.pvalue, rel=1e-7, abs=1e-300)
    ci = ref.confidence_interval(0.95)
    assert ours["pearson_ci"] == pytest.approx([ci.low, ci.high], abs=1e-12)


def test_betainc_against_scipy() -> None:
    from scipy.special import betainc

    for a, b, x in [(0.5, 0.5, 0.3), (10.0, 10.0, 0.01), (300.0, 300.0, 0.45), (2.0, 5.0, 0.9)]:
        assert betainc_regularized(a, b, x) == pytest.approx(betainc(a, b, x), rel=1e-10)


def test_pearson_undefined_for_constant_series_says_why() -> None:
    out = pearson(np.ones(50), np.arange(50.0))
    assert out["pearson_r"] is None
    assert out["pearson_p"] is None
    assert "reference series is constant" in out["pearson_reason"]
    assert pearson(np.arange(2.0), np.arange(2.0))["pearson_reason"].startswith("undefined")


def test_constant_axis_gives_null_r_in_json() -> None:
    t = np.arange(0.0, 5.0, 0.02)
    pos = np.column_stack([np.sin(t), np.zeros_like(t), np.zeros_like(t)])
    res = compare(_stream(t, pos), _stream(t, pos + 0.01))
    doc = res.to_json()
    assert doc["axes"]["x"]["pearson_r"] == pytest.approx(1.0)
    assert doc["axes"]["z"]["pearson_r"] is None
    assert "constant" in doc["axes"]["z"]["pearson_reason"]
    assert doc["axes"]["y"]["bias"] == pytest.approx(0.01)


def test_yaw_error_wraps_359_vs_1_to_2_degrees() -> None:
    t = np.arange(0.0, 1.0, 0.1)
    n = t.size
    ref = _stream(
        t,
        np.zeros((n, 3)),
        np.column_stack([np.zeros(n), np.zeros(n), np.full(n, np.radians(359.0))]),
    )
    oth = _stream(
        t,
        np.zeros((n, 3)),
        np.column_stack([np.zeros(n), np.zeros(n), np.full(n, np.radians(1.0))]),
    )
    res = compare(ref, oth)
    np.testing.assert_allclose(res.errors["yaw"], 2.0, atol=1e-9)
    np.testing.assert_allclose(res.errors["rotation_angle"], 2.0, atol=1e-6)


def test_correlation_of_turning_yaw_is_not_broken_by_wrapping() -> None:
    g = vehicle_motion(3000, seed=3)
    u = unity_view(g, convention="enu", latency=0.0, rate_hz=50.0)
    res = compare(g, u)
    assert res.stats["axes"]["yaw"]["pearson_r"] > 0.999


# ------------------------------------------------------------------ alignment


def test_umeyama_matches_evo_and_recovers_a_similarity() -> None:
    from evo.core.geometry import umeyama_alignment

    rng = np.random.default_rng(4)
    x = rng.normal(size=(200, 3))
    ang = 0.7
    r = np.array([[math.cos(ang), -math.sin(ang), 0], [math.sin(ang), math.cos(ang), 0], [0, 0, 1]])
    y = 1.5 * x @ r.T + np.array([1.0, -2.0, 3.0]) + rng.normal(scale=1e-3, size=x.shape)
    ours = umeyama(x, y, with_scale=True)
    theirs = umeyama_alignment(x.T, y.T, True)
    np.testing.assert_allclose(ours[0], theirs[0], atol=1e-12)
    np.testing.assert_allclose(ours[1], theirs[1], atol=1e-12)
    assert ours[2] == pytest.approx(theirs[2], rel=1e-12)
    assert ours[2] == pytest.approx(1.5, rel=1e-3)


def test_degenerate_alignment_is_an_error() -> None:
    t = np.arange(0.0, 2.0, 0.1)
    pos = np.column_stack([t, np.zeros_like(t), np.zeros_like(t)])  # a line
    with pytest.raises(AlignmentError, match="degenerate"):
        compare(_stream(t, pos), _stream(t, pos), align="se3")


def test_origin_alignment_makes_first_poses_coincide() -> None:
    g = vehicle_motion(500, seed=5)
    moved = g.with_(position=g.position + np.array([10.0, -4.0, 2.0]))
    res = compare(g, moved, align="origin", sync="nearest")
    assert res.errors["position_norm"][0] == pytest.approx(0.0, abs=1e-9)
    assert res.stats["position_error_norm"]["max"] < 1e-9
    assert res.stats["alignment"]["translation"] == pytest.approx([-10.0, 4.0, -2.0])


# ------------------------------------------------------------------ offset and latency


@pytest.mark.parametrize("clock_offset", [0.0, 0.0123, -3.7, 1000.25])
def test_offset_auto_recovers_clock_offset_to_sub_sample_precision(clock_offset: float) -> None:
    g = vehicle_motion(3000, rate_hz=50.0, seed=6)  # 60 s
    u = unity_view(g, convention="unity-flu", rate_hz=60.0, latency=0.0, clock_offset=clock_offset)
    est = estimate_offset(g, convert_stream(u, "enu"))
    # a sample-and-hold at 60 Hz shows poses on average half a Gazebo period late (10 ms)
    # plus half a render period; compare against the true content delay measured directly
    assert u.applied_stamp is not None
    true_delay = float(np.mean(u.t - u.applied_stamp)) * 1e-9 - clock_offset
    assert est.offset == pytest.approx(-clock_offset - true_delay, abs=0.004)
    assert 0 < est.uncertainty < 0.005


def test_offset_auto_on_interpolated_stream_is_precise() -> None:
    g = vehicle_motion(2000, rate_hz=50.0, seed=7)
    shifted = g.with_(t=g.t + np.int64(37_123_000))  # 37.123 ms: not a multiple of 20 ms
    res = compare(g, shifted, offset="auto")
    assert res.offset_s == pytest.approx(-0.037123, abs=2e-4)
    assert res.stats["position_error_norm"]["rmse"] < 5e-4
    assert res.stats["offset"]["estimate"]["uncertainty_s"] < 1e-3


def test_latency_from_applied_stamps() -> None:
    g = vehicle_motion(1000, seed=8)
    u = unity_view(g, latency=0.05, clock_offset=2.0)
    res = compare(g, u, offset=-2.0)
    lat = res.stats["latency"]
    assert lat["min_ms"] >= 50.0 - 1e-6
    assert lat["max_ms"] <= 50.0 + 20.0 + 1e-6  # + at most one Gazebo period of hold
    assert lat["n"] == len(u)


def test_constant_motion_offset_estimation_fails_clearly() -> None:
    t = np.arange(0.0, 10.0, 0.02)
    s = _stream(t, np.zeros((t.size, 3)))
    with pytest.raises(AlignmentError, match="constant"):
        estimate_offset(s, s)


# ------------------------------------------------------------------ frame doctor


@pytest.mark.parametrize("true_frame", ["unity-flu", "unity-enu", "ned", "enu"])
def test_doctor_names_the_convention(true_frame: str) -> None:
    g = vehicle_motion(1500, seed=9)
    raw = convert_stream(g, true_frame)
    diag = diagnose(g.position, g.orientation, raw.position, raw.orientation, "unity-flu")
    assert diag.best == true_frame
    if true_frame != "unity-flu":
        assert diag.warning is not None
        assert "fits worse" in diag.warning
    else:
        assert diag.warning is None


def test_doctor_reports_unknown_maps() -> None:
    g = vehicle_motion(800, seed=10)
    mirror = np.diag([1.0, -1.0, 1.0])  # a mirrored y axis: no known convention
    pos = g.position @ mirror.T
    from uwval.rotations import matrix_from_quat, quat_from_matrix

    r = mirror @ matrix_from_quat(g.orientation) @ mirror.T
    diag = diagnose(g.position, g.orientation, pos, quat_from_matrix(r), "unity-flu")
    assert diag.best is None
    assert "no known convention" in (diag.warning or "")
    np.testing.assert_array_equal(diag.world_axes, mirror)


def test_compare_frame_auto_picks_the_right_convention() -> None:
    g = vehicle_motion(1500, seed=11)
    u = unity_view(g, convention="unity-enu", rate_hz=50.0)
    mislabeled = u.with_(frame="unity-flu")  # the log claims FLU, the script used ENU
    bad = compare(g, mislabeled)
    assert any("fits worse than 'unity-enu'" in w for w in bad.warnings)
    good = compare(g, mislabeled, frame="auto")
    assert good.stats["frame"]["configured"] == "unity-enu"
    assert (
        good.stats["position_error_norm"]["rmse"] < 0.01 < bad.stats["position_error_norm"]["rmse"]
    )


def test_to_dataframe_has_aligned_series() -> None:
    g = vehicle_motion(300, seed=12)
    res = compare(g, g)
    df = res.to_dataframe()
    assert len(df) == res.n_samples
    assert {"t", "ref_x", "other_yaw", "err_position_norm"} <= set(df.columns)
    assert float(df["err_x"].abs().max()) == 0.0


@pytest.mark.parametrize("seed", [0, 1])
def test_frame_auto_and_offset_auto_together(seed: int) -> None:
    g = vehicle_motion(3000, rate_hz=50.0, seed=seed)
    u = unity_view(g, convention="unity-enu", rate_hz=60.0, clock_offset=42.0)
    res = compare(g, u.with_(frame="enu"), frame="auto", offset="auto")
    assert res.stats["frame"]["configured"] == "unity-enu"
    assert u.applied_stamp is not None
    delay = float(np.mean(u.t - u.applied_stamp)) * 1e-9 - 42.0
    assert res.offset_s == pytest.approx(-42.0 - delay, abs=0.004)
