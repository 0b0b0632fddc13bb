"""Issue 14: inputs that used to give a wrong number, a wrapped stamp or a traceback now get
a clear one-line error (API and CLI), and ``--offset auto`` ends for offsets of any size."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from cli_runner import run_uwval

from uwval.comparison import compare
from uwval.comparison.align import umeyama
from uwval.comparison.offset import estimate_offset
from uwval.comparison.synthetic import unity_view, vehicle_motion, write_pair_log
from uwval.errors import AlignmentError, PoseStreamError, UwvalError
from uwval.io.tum import write_tum
from uwval.posestream import MAX_ABS_STAMP_NS, PoseStream

EPOCH_NS = 1_800_000_000 * 10**9


def _quat(n: int) -> np.ndarray:
    return np.tile([0.0, 0.0, 0.0, 1.0], (n, 1))


# ------------------------------------------------------------------ PoseStream stamps
def test_epoch_nanoseconds_as_floats_are_refused_not_decimated() -> None:
    t = (EPOCH_NS + np.arange(100, dtype=np.int64) * 10_000_000).astype(np.float64)
    with pytest.raises(PoseStreamError, match="epoch nanoseconds stored as floats"):
        PoseStream.from_arrays(t, np.zeros((100, 3)), _quat(100))


def test_float_seconds_at_epoch_scale_still_work() -> None:
    t = 1.8e9 + np.arange(100) * 0.01
    s = PoseStream.from_arrays(t, np.zeros((100, 3)), _quat(100))
    assert len(s) == 100 and int(np.diff(s.t).min()) > 9_000_000


@pytest.mark.parametrize("last", [1e10, -1e10, 1e300])
def test_float_stamp_beyond_int64_nanoseconds_is_refused(last: float) -> None:
    t = np.arange(100, dtype=np.float64)
    t[-1] = last
    with pytest.raises(PoseStreamError, match="sample 99"):
        PoseStream.from_arrays(t, np.random.default_rng(0).random((100, 3)), _quat(100))


def test_int_stamps_whose_differences_would_wrap_are_refused() -> None:
    t = np.arange(10, dtype=np.int64)
    t[0], t[-1] = np.iinfo(np.int64).min, np.iinfo(np.int64).max
    with pytest.raises(PoseStreamError, match="overflow int64"):
        PoseStream.from_arrays(t, np.zeros((10, 3)), _quat(10))
    with pytest.raises(PoseStreamError, match="overflow int64"):
        PoseStream(t=np.sort(t), position=np.zeros((10, 3)), orientation=_quat(10))
    ok = np.array([-MAX_ABS_STAMP_NS, MAX_ABS_STAMP_NS], dtype=np.int64)
    assert len(PoseStream.from_arrays(ok, np.zeros((2, 3)), _quat(2))) == 2


# ------------------------------------------------------------------ values given to compare
def test_nan_positions_are_refused_not_a_perfect_correlation() -> None:
    g = vehicle_motion(300)
    bad = g.position.copy()
    bad[:, 0] = np.nan
    nan_stream = PoseStream(t=g.t, position=bad, orientation=g.orientation, topic="/u")
    with pytest.raises(PoseStreamError, match=r"/u.*sample 0 .*NaN"):
        compare(g, nan_stream)


@pytest.mark.parametrize("align", ["none", "se3", "sim3"])
def test_huge_positions_are_refused_not_a_null_rmse(align: str) -> None:
    g = vehicle_motion(300)
    big = g.with_(position=g.position * 1e300)
    with pytest.raises(PoseStreamError, match="beyond 1e\\+09 m"):
        compare(g, big, align=align)


def test_umeyama_on_overflowing_points_is_an_alignment_error() -> None:
    x = np.random.default_rng(1).random((50, 3)) * 1e300
    with pytest.raises(AlignmentError, match="not finite"):
        umeyama(x, x)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"offset": 1e10}, "offset must be"),
        ({"offset": 1e300}, "offset must be"),
        ({"offset": "1e300"}, "offset must be"),
        ({"offset": float("nan")}, "offset must be"),
        ({"max_gap": 1e300}, "max_gap must be"),
        ({"max_gap": float("nan")}, "max_gap must be"),
        ({"max_diff": 1e300, "sync": "nearest"}, "max_diff must be"),
        ({"offset": "auto", "max_offset": float("nan")}, "max_offset must be"),
        ({"offset": "auto", "max_offset": -1.0}, "max_offset must be"),
    ],
)
def test_out_of_range_options_are_uwval_errors(kwargs: dict, match: str) -> None:
    g = vehicle_motion(300)
    with pytest.raises(UwvalError, match=match):
        compare(g, g, **kwargs)


def test_estimate_offset_refuses_nan_bound_and_accepts_a_huge_one() -> None:
    g = vehicle_motion(600)
    with pytest.raises(AlignmentError, match="max_offset"):
        estimate_offset(g, g, max_offset=float("nan"))
    assert abs(estimate_offset(g, g, max_offset=1e300).offset) < 1e-6


# ------------------------------------------------------------------ offset auto, any size
@pytest.mark.parametrize("clock_offset", [1.8e9, -1.8e9, 0.3])
def test_offset_auto_finds_epoch_size_offsets(clock_offset: float) -> None:
    """A Unity clock 1.8e9 s off (epoch against monotonic) used to loop forever in the
    golden-section refinement (tolerance below the float spacing at 1.8e9 s)."""
    t0 = EPOCH_NS if clock_offset < 0 else 0
    g = vehicle_motion(1250, t0_ns=t0)  # 25 s at 50 Hz
    u = unity_view(g, clock_offset=clock_offset, latency=0.01)
    r = compare(g, u, offset="auto")
    # the estimate absorbs the 10 ms latency plus the sample-and-hold half period
    assert abs(r.offset_s + clock_offset + 0.018) < 0.005
    assert r.stats["axes"]["x"]["mae"] < 0.01
    assert r.offset_estimate is not None and r.offset_estimate.note is None


def test_offset_auto_says_when_the_motion_repeats() -> None:
    """The synthetic path repeats every 800 pi s: over an hour two offsets fit equally.
    (Without applied stamps, which would give the offset whatever the motion.)"""
    g = vehicle_motion(180_000)  # one hour at 50 Hz
    u = unity_view(g, clock_offset=1.8e9).with_(applied_stamp=None)
    r = compare(g, u, offset="auto")
    assert any("the motion repeats" in w for w in r.warnings)
    assert "the motion repeats" in r.to_json()["offset"]["estimate"]["note"]


# ------------------------------------------------------------------ the same through the CLI
@pytest.fixture(scope="module")
def tum_pair(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    d = tmp_path_factory.mktemp("tum")
    g = vehicle_motion(300)
    write_tum(d / "a.tum", g)
    g2 = vehicle_motion(300, seed=3)
    write_tum(d / "big.tum", g2.with_(position=g2.position * 1e300))
    return d / "a.tum", d / "big.tum"


@pytest.mark.parametrize(
    "args",
    [
        ["--offset", "1e10"],
        ["--offset", "1e300"],
        ["--max-gap", "1e300"],
        ["--offset", "auto", "--max-offset", "nan"],
    ],
)
def test_cli_out_of_range_options_are_one_line_errors(
    tum_pair: tuple[Path, Path], args: list[str]
) -> None:
    a, _ = tum_pair
    p = run_uwval("compare", a, a, *args)
    assert p.returncode == 2, p.stderr
    assert "Traceback" not in p.stderr and "error:" in p.stderr
    assert len(p.stderr.strip().splitlines()) == 1


def test_cli_huge_tum_positions_with_se3_are_a_one_line_error(
    tum_pair: tuple[Path, Path],
) -> None:
    a, big = tum_pair
    p = run_uwval("compare", a, big, "--align", "se3")
    assert p.returncode == 2 and "Traceback" not in p.stderr
    assert "big.tum" in p.stderr and "beyond 1e+09 m" in p.stderr


def test_cli_offset_auto_with_an_epoch_clock_offset_returns(tmp_path: Path) -> None:
    g = vehicle_motion(1250, t0_ns=EPOCH_NS)
    u = unity_view(g, clock_offset=-1.8e9, latency=0.01)
    log = write_pair_log(tmp_path / "pair.mcap", g, u)
    p = run_uwval("compare", log, "--offset", "auto", "--json", timeout=120)
    assert p.returncode in (0, 1), p.stderr
    doc = json.loads(p.stdout)
    assert abs(doc["offset"]["applied_s"] - 1.8e9 + 0.018) < 0.005


def test_report_of_a_log_named_with_dollars(tmp_path: Path) -> None:
    """matplotlib read ``$5_and_$`` as mathtext and the report died with a ParseException."""
    g = vehicle_motion(500)
    log = write_pair_log(tmp_path / "price_$5_and_$6.mcap", g, unity_view(g, latency=0.02))
    p = run_uwval("report", log, "-o", tmp_path / "r.html", timeout=300)
    assert p.returncode in (0, 1), p.stderr
    assert "Traceback" not in p.stderr and (tmp_path / "r.html").stat().st_size > 10_000


# ------------------------------------------------------------------ options as enums
def test_options_are_enums_and_their_strings_still_work() -> None:
    from uwval.batch.executors import EXECUTORS, Executor
    from uwval.comparison import AlignMode, SyncMethod

    g = vehicle_motion(300)
    u = unity_view(g, latency=0.02)
    by_enum = compare(g, u, sync=SyncMethod.NEAREST, align=AlignMode.SE3).to_json()
    by_str = compare(g, u, sync="nearest", align="se3").to_json()
    assert by_enum == by_str
    assert json.dumps(by_enum["sync"]["method"]) == '"nearest"'
    assert by_enum["alignment"]["mode"] == "se3" and type(by_enum["alignment"]["mode"]) is str
    assert EXECUTORS == ("local", "dask", "inline") and Executor("dask") == "dask"
    with pytest.raises(AlignmentError, match="unknown sync method"):
        compare(g, u, sync="linear")


def test_cli_offset_auto_uses_applied_stamps_when_the_motion_cannot_tell(tmp_path: Path) -> None:
    """Issue 17: Unity on an epoch clock, Gazebo on sim time, a vehicle at constant speed (no
    motion feature to lock on). The log's applied stamps give the offset directly."""
    log = tmp_path / "p.mcap"
    run_uwval(
        "simulate", "--duration", "5", "--unity-clock-offset", "1800000000", "-o", log, check=True
    )
    result = run_uwval("compare", log, "--offset", "auto", "--json")
    assert result.returncode == 0, result.stderr
    doc = json.loads(result.stdout)
    rows = list(doc.get("topics", {}).values()) or [doc]
    assert rows
    for row in rows:
        est = row["offset"]["estimate"]
        assert est["signal"] == "applied_stamps"
        assert abs(row["offset"]["applied_s"] + 1.8e9) < 0.02  # minus the median latency
        assert "applied stamp" in est["method"]
