"""The compare engine's fast paths (issue 15) give the numbers of straightforward references.

Each rewritten routine is checked against a plain formula written here (per-pair slerp, per
sample interpolation, numpy's own statistics, mcap's own reader), to the bit where the
arithmetic is the same and to 1e-12 where the reference computes differently; a seeded
comparison is pinned end to end to such a reference.
"""

from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from uwval.comparison import compare
from uwval.comparison.engine import _error_series
from uwval.comparison.logs import _recorded_clock_offset
from uwval.comparison.offset import latency_stats
from uwval.comparison.stats import axis_stats, norm_stats, pearson
from uwval.comparison.sync import interpolate_at, nominal_period_ns
from uwval.comparison.synthetic import unity_view, vehicle_motion, write_pair_log
from uwval.errors import PoseStreamError
from uwval.frames import convert_stream
from uwval.io.mcap_meta import summary_metadata
from uwval.posestream import PoseStream, quat_norms
from uwval.rotations import (
    geodesic_angle,
    geodesic_deg,
    quat_multiply,
    rpy_from_quat,
    slerp,
    slerp_segments,
    wrap_deg,
)

REL = 1e-12


def _unit_quats(rng: np.random.Generator, n: int) -> np.ndarray:
    q = rng.normal(size=(n, 4))
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def _textbook_slerp(q0: np.ndarray, q1: np.ndarray, s: float) -> np.ndarray:
    """One slerp, short arc, as in any textbook (nlerp when the two are nearly equal)."""
    d = float(q0 @ q1)
    if d < 0:
        q1, d = -q1, -d
    theta = math.acos(min(d, 1.0))
    if math.sin(theta) < 1e-9:
        out = (1 - s) * q0 + s * q1
    else:
        out = (math.sin((1 - s) * theta) * q0 + math.sin(s * theta) * q1) / math.sin(theta)
    return out / np.linalg.norm(out)


def test_slerp_segments_equals_slerp_to_the_bit_and_the_textbook() -> None:
    rng = np.random.default_rng(1)
    q0 = _unit_quats(rng, 300)
    q1 = _unit_quats(rng, 300)
    q1[::3] = -q0[::3] * (1 + 1e-13)  # opposite signs of one rotation: the short arc
    q1[1::7] = q0[1::7]  # equal pairs: the nlerp branch
    seg = np.sort(rng.integers(0, 300, 1000))
    s = rng.random(1000)
    s[:5] = (0.0, 1.0, 0.5, 0.0, 1.0)
    got = slerp_segments(q0, q1, s, seg)
    assert np.array_equal(got, slerp(q0[seg], q1[seg], s))
    out = np.empty((1000, 4))
    assert slerp_segments(q0[seg], q1[seg], s, out=out) is out
    assert np.array_equal(out, got)
    want = np.array([_textbook_slerp(q0[i], q1[i], f) for i, f in zip(seg, s, strict=True)])
    # q and -q are one rotation: compare up to sign
    sign = np.sign(np.einsum("ij,ij->i", got, want))
    np.testing.assert_allclose(got * sign[:, None], want, rtol=0, atol=REL)


def _reference_interpolation(
    stream: PoseStream, tq: np.ndarray, max_gap_ns: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per query stamp: bracketing pair, lerp, textbook slerp; invalid outside or in a gap."""
    t = stream.t
    pos, quat, valid = np.zeros((tq.size, 3)), np.zeros((tq.size, 4)), np.zeros(tq.size, bool)
    for k, q in enumerate(tq):
        if q < t[0] or q > t[-1]:
            continue
        hi = min(max(int(np.searchsorted(t, q, side="left")), 1), t.size - 1)
        lo = hi - 1
        if t[hi] - t[lo] > max_gap_ns and q not in (t[lo], t[hi]):
            continue
        f = float(q - t[lo]) / float(t[hi] - t[lo])
        p0, p1 = stream.position[lo], stream.position[hi]
        pos[k] = p0 + f * (p1 - p0)
        quat[k] = _textbook_slerp(stream.orientation[lo], stream.orientation[hi], f)
        valid[k] = True
    return pos, quat, valid


@pytest.mark.parametrize(("denser", "shuffled"), [(False, False), (True, False), (False, True)])
def test_interpolation_equals_a_per_sample_reference(denser: bool, shuffled: bool) -> None:
    rng = np.random.default_rng(2)
    n = 400
    t = np.cumsum(rng.integers(8_000_000, 12_000_000, n)).astype(np.int64)
    t[200:] += 200_000_000  # one long gap
    q = _unit_quats(rng, n) * np.where(rng.random(n) < 0.5, -1.0, 1.0)[:, None]
    q[100:150] = q[100]  # a stretch without rotation
    stream = PoseStream(t=t, position=np.cumsum(rng.normal(size=(n, 3)), axis=0), orientation=q)
    m = 60 if denser else 700  # fewer queries than poses: the per-query branch
    tq = np.sort(rng.integers(t[0] - 50_000_000, t[-1] + 50_000_000, m))
    tq[:4] = (t[0], t[199], t[200], t[-1])  # exact hits, two of them beside the gap
    tq.sort()
    if shuffled:  # stamps in any order (the fast paths assume sorted ones)
        tq = rng.permutation(tq)
    got = interpolate_at(stream, tq)
    pos, quat, valid = _reference_interpolation(stream, tq, 5 * nominal_period_ns(t))
    assert np.array_equal(got.valid, valid)
    assert got.outside == int(((tq < t[0]) | (tq > t[-1])).sum())
    assert got.in_gap == int((~valid).sum()) - got.outside > 0
    np.testing.assert_allclose(got.position[valid], pos[valid], rtol=REL, atol=REL)
    sign = np.sign(np.einsum("ij,ij->i", got.orientation[valid], quat[valid]))
    np.testing.assert_allclose(
        got.orientation[valid] * sign[:, None], quat[valid], rtol=0, atol=REL
    )


def test_error_series_equal_rpy_wrap_and_geodesic_to_the_bit() -> None:
    rng = np.random.default_rng(3)
    n = 40_000  # several row steps
    a, b = _unit_quats(rng, n), _unit_quats(rng, n)
    b[:100] = a[:100]  # equal orientations: exact zeros
    pa, pb = rng.normal(size=(n, 3)), rng.normal(size=(n, 3))
    errs = _error_series(pa, a, pb, b)
    want = wrap_deg(np.degrees(rpy_from_quat(b)) - np.degrees(rpy_from_quat(a)))
    for j, ax in enumerate(("roll", "pitch", "yaw")):
        assert np.array_equal(errs[ax], want[:, j])
    assert np.array_equal(errs["rotation_angle"], np.degrees(geodesic_angle(b, a)))
    assert np.array_equal(geodesic_deg(b, a, chunk=7), np.degrees(geodesic_angle(b, a)))
    assert (errs["rotation_angle"][:100] == 0.0).all()
    np.testing.assert_array_equal(errs["position_norm"], np.linalg.norm(pb - pa, axis=1))
    # the relative rotation's angle by the quaternion product, for an independent check
    rel = quat_multiply(a * np.array([-1.0, -1.0, -1.0, 1.0]), b)
    ang = np.degrees(2 * np.arctan2(np.linalg.norm(rel[:, :3], axis=1), np.abs(rel[:, 3])))
    np.testing.assert_allclose(errs["rotation_angle"], ang, rtol=REL, atol=1e-10)


@pytest.mark.parametrize("n", [1, 2, 3, 1000, 1001])
def test_statistics_equal_numpy(n: int) -> None:
    rng = np.random.default_rng(n)
    e = rng.normal(size=n) * 0.01
    ref = np.cumsum(rng.normal(size=n))
    oth = ref + e
    ns = norm_stats(np.abs(e))
    ae = np.abs(e)
    assert ns == {
        "mean": float(np.mean(ae)),
        "median": float(np.median(ae)),
        "std": float(np.std(ae)),
        "min": float(np.min(ae)),
        "max": float(np.max(ae)),
        "rmse": math.sqrt(float(np.mean(np.power(ae, 2)))),
        "sse": float(np.sum(np.power(ae, 2))),
    }
    st = axis_stats(e, ref, oth.copy(), overwrite_other=True)
    assert st["mae"] == float(ae.mean()) and st["max"] == float(ae.max())
    assert st["median"] == float(np.median(ae)) and st["p95"] == float(np.percentile(ae, 95))
    assert st["bias"] == float(e.mean()) and st["std"] == float(e.std())
    assert st["rmse"] == pytest.approx(math.sqrt(float(np.mean(e * e))), rel=REL)
    if n >= 3:
        assert st["pearson_r"] == pytest.approx(float(np.corrcoef(ref, oth)[0, 1]), rel=REL)
        assert pearson(ref, oth) == {k: v for k, v in st.items() if k.startswith("pearson")}


def test_norm_stats_with_nan_gives_nan_median_as_numpy() -> None:
    e = np.array([0.1, np.nan, 0.3])
    assert math.isnan(norm_stats(e)["median"]) and math.isnan(norm_stats(e)["mean"])


def test_quaternion_norms_and_renormalisation_equal_numpy() -> None:
    rng = np.random.default_rng(5)
    n = 5000
    q = _unit_quats(rng, n)
    assert np.array_equal(quat_norms(q), np.linalg.norm(q, axis=1))
    t = np.arange(n, dtype=np.int64) * 10_000_000
    pos = rng.normal(size=(n, 3))
    # unit to 1e-15: untouched, values and all
    s = PoseStream.from_arrays(t, pos, q)
    assert "renormalized" not in s.repairs and np.array_equal(s.orientation, q)
    # rows just inside / outside 1e-9 of unit norm: decided by numpy's exact norm
    q2 = q.copy()
    q2[10] *= 1 + 0.999e-9
    q2[20] *= 1 + 1.001e-9
    q2[30] *= 1 - 1.001e-9
    norms = np.linalg.norm(q2, axis=1)
    s2 = PoseStream.from_arrays(t, pos, q2)
    assert s2.repairs["renormalized"] == int((np.abs(norms - 1.0) > 1e-9).sum()) == 2
    assert np.array_equal(s2.orientation, q2 / norms[:, None])
    # rounded quaternions (text logs): every row divided by its norm, as before
    q3 = np.round(q, 4)
    s3 = PoseStream.from_arrays(t, pos, q3)
    assert np.array_equal(s3.orientation, q3 / np.linalg.norm(q3, axis=1)[:, None])
    q4 = q.copy()
    q4[7] *= 1.5
    with pytest.raises(PoseStreamError, match=r"sample 7 has norm 1\.5"):
        PoseStream.from_arrays(t, pos, q4)
    pos[9, 1] = np.inf
    with pytest.raises(PoseStreamError, match=r"sample 9 \(t=90000000 ns\) has a NaN or inf"):
        PoseStream.from_arrays(t, pos, q)


def test_checked_stamps_are_read_only_and_other_stamps_still_checked() -> None:
    rng = np.random.default_rng(6)
    n = 50
    t = np.arange(n, dtype=np.int64)[::-1].copy()  # reversed: sorted by from_arrays
    s = PoseStream.from_arrays(t, rng.normal(size=(n, 3)), _unit_quats(rng, n))
    assert s.repairs["sorted"] == n - 1
    with pytest.raises(ValueError):
        s.t[0] = 5
    assert len(s.with_(frame="ned")) == n and len(s.slice(slice(10, 20))) == 10
    for bad in (s.t[::-1], s.t.copy()[::-1], np.array([3, 2, 1], dtype=np.int64)):
        k = len(bad)
        with pytest.raises(PoseStreamError, match="strictly increasing"):
            PoseStream(
                t=bad, position=np.zeros((k, 3)), orientation=np.tile([0, 0, 0, 1.0], (k, 1))
            )


def test_nominal_period_and_latency_equal_numpy() -> None:
    rng = np.random.default_rng(7)
    for n in (2, 3, 4, 101, 1000):
        t = np.cumsum(rng.integers(1, 30, n)).astype(np.int64)
        assert nominal_period_ns(t) == int(np.median(np.diff(t)))
    t = np.cumsum(rng.integers(15_000_000, 18_000_000, 1001)).astype(np.int64)
    applied = t - rng.integers(10_000_000, 40_000_000, t.size)
    s = PoseStream(
        t=t,
        position=np.zeros((t.size, 3)),
        orientation=np.tile([0.0, 0.0, 0.0, 1.0], (t.size, 1)),
        applied_stamp=applied,
    )
    lat = (t - applied).astype(np.float64) * 1e-6
    got = latency_stats(s)
    assert got is not None
    assert got["median_ms"] == float(np.median(lat))
    assert got["p95_ms"] == float(np.percentile(lat, 95))


def _reference_compare(ref: PoseStream, other: PoseStream) -> dict[str, dict[str, float]]:
    """uwval compare's statistics (interp sync, no offset or alignment) from plain formulas."""
    oth = convert_stream(other, "enu")
    pos, quat, valid = _reference_interpolation(oth, ref.t, 5 * int(np.median(np.diff(oth.t))))
    rp, rq, op, oq = ref.position[valid], ref.orientation[valid], pos[valid], quat[valid]
    out: dict[str, dict[str, float]] = {"n": {"samples": int(valid.sum())}}

    def stats(e: np.ndarray, a: np.ndarray, b: np.ndarray) -> dict[str, float]:
        ae = np.abs(e)
        return {
            "mae": ae.mean(),
            "rmse": math.sqrt(np.mean(e**2)),
            "max": ae.max(),
            "p95": np.percentile(ae, 95),
            "median": np.median(ae),
            "bias": e.mean(),
            "std": e.std(),
            "pearson_r": np.corrcoef(a, b)[0, 1],
        }

    for j, ax in enumerate("xyz"):
        out[ax] = stats(op[:, j] - rp[:, j], rp[:, j], op[:, j])
    r_deg, o_deg = np.degrees(rpy_from_quat(rq)), np.degrees(rpy_from_quat(oq))
    for j, ax in enumerate(("roll", "pitch", "yaw")):
        e = (o_deg[:, j] - r_deg[:, j] + 180.0) % 360.0 - 180.0
        cont = np.unwrap(r_deg[:, j], period=360.0)
        out[ax] = stats(e, cont, cont + e)
    norm = np.linalg.norm(op - rp, axis=1)
    rel = quat_multiply(rq * np.array([-1.0, -1.0, -1.0, 1.0]), oq)
    ang = np.degrees(2 * np.arctan2(np.linalg.norm(rel[:, :3], axis=1), np.abs(rel[:, 3])))
    for name, e in (("position_error_norm", norm), ("rotation_error_deg", ang)):
        out[name] = {
            "mean": e.mean(),
            "median": np.median(e),
            "std": e.std(),
            "max": e.max(),
            "rmse": math.sqrt(np.mean(e**2)),
        }
    return out


def test_a_seeded_comparison_equals_the_reference() -> None:
    g = vehicle_motion(3000, 50.0, seed=11)
    u = unity_view(g, rate_hz=60.0, latency=0.02, noise=0.01, seed=12)
    res = compare(g, u)
    want = _reference_compare(g, u)
    got = res.stats
    # Unity starts 20 ms late and ends early: a few reference stamps lie outside its span
    assert got["n_samples"] == want.pop("n")["samples"] > 2990
    for ax in ("x", "y", "z", "roll", "pitch", "yaw"):
        for key, value in want[ax].items():
            assert got["axes"][ax][key] == pytest.approx(value, rel=REL, abs=REL), (ax, key)
    for sec in ("position_error_norm", "rotation_error_deg"):
        for key, value in want[sec].items():
            assert got[sec][key] == pytest.approx(value, rel=REL, abs=1e-10), (sec, key)


def _write_mcap_with_metadata(
    path: Path, records: list[tuple[str, dict[str, str]]], **kw: bool
) -> None:
    from mcap.writer import Writer

    with open(path, "wb") as fh:
        w = Writer(fh, **kw)  # type: ignore[arg-type]
        w.start("ros2", "uwval-test")
        sid = w.register_schema("std_msgs/msg/Empty", "ros2msg", b"")
        cid = w.register_channel("/x", "cdr", sid)
        w.add_message(cid, log_time=1, data=b"\x00\x01\x00\x00", publish_time=1)
        for name, data in records:
            w.add_metadata(name, data)
        w.finish()


def _mcap_reader_metadata(path: Path, name: str) -> list[dict[str, str]]:
    from mcap.reader import make_reader

    with open(path, "rb") as fh:
        return [dict(r.metadata) for r in make_reader(fh).iter_metadata() if r.name == name]


@pytest.mark.parametrize("offsets", [True, False])
def test_recorded_clock_offset_reads_the_metadata_as_mcaps_reader(
    tmp_path: Path, offsets: bool
) -> None:
    clock = {
        "unity_clock": "monotonic",
        "epoch_minus_monotonic_ns": "1700000000123456789",
        "unity_clock_offset_ns": "-2500",
    }
    log = tmp_path / "clock.mcap"
    records = [
        ("other", {"a": "b"}),
        ("uwval.clock", {"unity_clock": "epoch"}),
        ("uwval.clock", clock),
    ]
    _write_mcap_with_metadata(log, records, use_summary_offsets=offsets)
    assert summary_metadata(log, "uwval.clock") == _mcap_reader_metadata(log, "uwval.clock")
    assert _recorded_clock_offset(log) == (1700000000123456789 + 2500) * 1e-9
    plain = tmp_path / "plain.mcap"
    _write_mcap_with_metadata(
        plain, [("uwval.clock", {"unity_clock": "epoch"})], use_summary_offsets=offsets
    )
    assert _recorded_clock_offset(plain) is None
    none = tmp_path / "none.mcap"
    _write_mcap_with_metadata(none, [], use_summary_offsets=offsets)
    assert summary_metadata(none, "uwval.clock") == [] and _recorded_clock_offset(none) is None


def test_recorded_clock_offset_of_a_log_without_summary_or_damaged(tmp_path: Path) -> None:
    clock = {"unity_clock": "monotonic", "epoch_minus_monotonic_ns": "42000000000"}
    log = tmp_path / "clock.mcap"
    _write_mcap_with_metadata(log, [("uwval.clock", clock)])
    data = log.read_bytes()
    cut = tmp_path / "cut.mcap"  # a recorder killed before the summary: mcap's reader scans
    cut.write_bytes(data[:-40])
    assert summary_metadata(cut, "uwval.clock") is None
    assert _recorded_clock_offset(cut) == _recorded_clock_offset_by_scan(cut)
    bad = tmp_path / "bad.mcap"  # summary offsets pointing past the file: mcap's reader decides
    footer = data[-37:]
    bad.write_bytes(data[:-37] + footer[:17] + (10**12).to_bytes(8, "little") + footer[25:])
    with pytest.raises(ValueError, match="outside the file"):
        summary_metadata(bad, "uwval.clock")
    assert _recorded_clock_offset(bad) == _recorded_clock_offset_by_scan(bad)


def _recorded_clock_offset_by_scan(path: Path) -> float | None:
    try:
        for m in _mcap_reader_metadata(path, "uwval.clock"):
            if m.get("unity_clock") == "monotonic":
                return (
                    int(m["epoch_minus_monotonic_ns"]) - int(m.get("unity_clock_offset_ns", "0"))
                ) * 1e-9
    except Exception:
        return None
    return None


def test_a_default_compare_imports_neither_numpy_ma_nor_mcaps_reader(tmp_path: Path) -> None:
    g = vehicle_motion(500, seed=4)
    log = write_pair_log(tmp_path / "run.mcap", g, unity_view(g, seed=5))
    code = (
        "import sys\n"
        "from uwval.cli import main\n"
        "try:\n"
        f"    main(['compare', {str(log)!r}, '--json'])\n"
        "except SystemExit:\n"
        "    pass\n"
        "mods = ('numpy.ma', 'mcap.reader', 'scipy', 'pandas', 'matplotlib', 'jinja2')\n"
        "print('LOADED', [m for m in mods if m in sys.modules])\n"
    )
    proc = subprocess.run(
        [sys.executable, "-c", code],
        capture_output=True,
        text=True,
        timeout=60,
        stdin=subprocess.DEVNULL,
    )
    assert proc.returncode == 0, proc.stderr
    assert "LOADED []" in proc.stdout


def test_pairs_compared_in_threads_give_the_sequential_results(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from uwval.comparison import logs
    from uwval.comparison.synthetic import camera_motion

    g = vehicle_motion(3000, 100.0, seed=31)
    u = unity_view(g, rate_hz=60.0, latency=0.02, noise=0.003, seed=32)
    cam = camera_motion(g)
    cam_u = unity_view(cam, rate_hz=60.0, latency=0.02, seed=33, topic="/unity/gui_camera_pose")
    log = write_pair_log(tmp_path / "two.mcap", g, u, camera=(cam, cam_u))
    monkeypatch.setattr(logs, "PARALLEL_MIN_SAMPLES", 10**9)
    one_by_one = logs.compare_logs(log).to_json()
    threads: list[str] = []
    real_compare = compare

    def spy(*args: object, **kw: object) -> object:
        import threading

        threads.append(threading.current_thread().name)
        return real_compare(*args, **kw)  # type: ignore[arg-type]

    monkeypatch.setattr(logs, "compare", spy)
    monkeypatch.setattr(logs, "PARALLEL_MIN_SAMPLES", 1000)
    assert logs.compare_logs(log).to_json() == one_by_one
    assert len(threads) == 2 and all(t.startswith("uwval-compare") for t in threads)
    assert list(one_by_one["topics"]) == ["model_rov_pose", "gui_camera_pose"]


def test_an_error_of_the_first_pair_is_raised_as_one_by_one(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from uwval.comparison import logs
    from uwval.comparison.synthetic import camera_motion
    from uwval.errors import AlignmentError

    g = vehicle_motion(2000, 100.0, seed=41)
    cam = camera_motion(g)
    log = write_pair_log(
        tmp_path / "two.mcap",
        g,
        unity_view(g, seed=42),
        camera=(cam, unity_view(cam, seed=43, topic="/unity/gui_camera_pose")),
    )
    monkeypatch.setattr(logs, "PARALLEL_MIN_SAMPLES", 100)
    # an offset that leaves no overlap: both pairs fail, the vehicle pair's error is raised
    with pytest.raises(AlignmentError, match="model_rov_pose"):
        logs.compare_logs(log, offset=1e6)
