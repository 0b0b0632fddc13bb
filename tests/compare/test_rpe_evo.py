"""``uwval rpe`` equals evo_rpe 1.38.1 (issue 16 item 1).

Expected values were produced with evo 1.38.1 by (D = /work/shared/data/evo):

    evo_rpe tum $D/<ref> $D/<est> <flags> --save_results out.zip --no_warnings --silent
    # FR1 = freiburg1_xyz-groundtruth.txt $D/freiburg1_xyz-rgbdslam.txt
    # FR2 = fr2_desk_groundtruth.txt $D/fr2_desk_ORB.txt
    # then: unzip -p out.zip stats.json

(evo's defaults: -r trans_part -d 1 -u f --t_max_diff 0.01.) The same <flags> are given to
``uwval rpe``, which accepts evo's spellings. Values are hard-coded, so the test does not
depend on evo being installed; a second test compares the pairs themselves with evo's when
evo is importable, and a property test checks the vectorised core against a slow per-pair
4 x 4 matrix reference written here.
"""

from __future__ import annotations

import itertools
import json
import math
import shutil
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from uwval.cli import main
from uwval.comparison.rpe import RELATIONS, rpe
from uwval.errors import AlignmentError
from uwval.io.tum import read_tum
from uwval.posestream import PoseStream

DATA = Path(__file__).resolve().parents[3] / "shared" / "data" / "evo"
PAIRS = {
    "fr1": ("freiburg1_xyz-groundtruth.txt", "freiburg1_xyz-rgbdslam.txt"),
    "fr2": ("fr2_desk_groundtruth.txt", "fr2_desk_ORB.txt"),
}
needs_data = pytest.mark.skipif(not DATA.is_dir(), reason="shared evo data not present")

# (pair, evo_rpe flags, evo's stats.json)
EVO_RPE = [
    # evo_rpe tum $D/$FR1 --t_max_diff 0.01
    (
        "fr1",
        "--t_max_diff 0.01",
        dict(
            rmse=0.005764370848928318,
            mean=0.00481560947020396,
            median=0.004138857799364448,
            std=0.003168260834346898,
            min=0.00017106115346223795,
            max=0.020865814532329843,
            sse=0.026050729486636066,
        ),
    ),
    # evo_rpe tum $D/$FR1 -r rot_part
    (
        "fr1",
        "-r rot_part",
        dict(
            rmse=0.008728074016289191,
            mean=0.007412349927933645,
            median=0.006470288184664273,
            std=0.004608290852331763,
            min=0.0004180541428258354,
            max=0.04031276395531378,
            sse=0.05972455241051687,
        ),
    ),
    # evo_rpe tum $D/$FR1 -r full
    (
        "fr1",
        "-r full",
        dict(
            rmse=0.010459791934727817,
            mean=0.00907652176719662,
            median=0.00798224939603954,
            std=0.005198461303828572,
            min=0.001130377570538521,
            max=0.04539274340480462,
            sse=0.08577528189715293,
        ),
    ),
    # evo_rpe tum $D/$FR1 -r angle_deg -d 10
    (
        "fr1",
        "-r angle_deg -d 10",
        dict(
            rmse=0.7015713582109036,
            mean=0.6287920052513384,
            median=0.5967202092589023,
            std=0.31116391949243233,
            min=0.06013580403727554,
            max=1.593852916721274,
            sse=38.391784911627575,
        ),
    ),
    # evo_rpe tum $D/$FR1 -r angle_rad -as
    (
        "fr1",
        "-r angle_rad -as",
        dict(
            rmse=0.0061717139386166815,
            mean=0.005241338606301212,
            median=0.0045751886421161745,
            std=0.0032585921122797656,
            min=0.00029560892037159474,
            max=0.028506393947576997,
            sse=0.029862601505050497,
        ),
    ),
    # evo_rpe tum $D/$FR1 -r point_distance -d 5
    (
        "fr1",
        "-r point_distance -d 5",
        dict(
            rmse=0.00779274991706822,
            mean=0.005768304201328534,
            median=0.004644429331364299,
            std=0.0052396200158887785,
            min=0.0002567642814029422,
            max=0.026912650477709882,
            sse=0.009473404398114811,
        ),
    ),
    # evo_rpe tum $D/$FR1 -d 0.1 -u m
    (
        "fr1",
        "-d 0.1 -u m",
        dict(
            rmse=0.014305008942373859,
            mean=0.012548034394815485,
            median=0.01155941612413828,
            std=0.006868778178680948,
            min=0.001541305581211194,
            max=0.03865418101949766,
            sse=0.016370662467311684,
        ),
    ),
    # evo_rpe tum $D/$FR1 -d 0.1 -u m --all_pairs
    (
        "fr1",
        "-d 0.1 -u m --all_pairs",
        dict(
            rmse=0.013291982122954692,
            mean=0.011531665966548485,
            median=0.010487808708040967,
            std=0.006610406098939344,
            min=0.00037822826434908254,
            max=0.04433832445132808,
            sse=0.1286207022150575,
        ),
    ),
    # evo_rpe tum $D/$FR1 -d 10 --all_pairs -as
    (
        "fr1",
        "-d 10 --all_pairs -as",
        dict(
            rmse=0.014091438854574463,
            mean=0.012039805751613083,
            median=0.01087356509776972,
            std=0.007322002899182393,
            min=0.00046647688218242207,
            max=0.04829771513416908,
            sse=0.1538907029689634,
        ),
    ),
    # evo_rpe tum $D/$FR1 -d 1 -u d -r angle_deg
    (
        "fr1",
        "-d 1 -u d -r angle_deg",
        dict(
            rmse=0.44857617989736404,
            mean=0.38846786910349235,
            median=0.3276423780268848,
            std=0.22430627241676546,
            min=0.03572261300276099,
            max=1.37549012255041,
            sse=67.81133855073224,
        ),
    ),
    # evo_rpe tum $D/$FR1 -d 0.05 -u r --all_pairs
    (
        "fr1",
        "-d 0.05 -u r --all_pairs",
        dict(
            rmse=0.01421606048074636,
            mean=0.012393862646376137,
            median=0.011009891428267134,
            std=0.006963371618332652,
            min=0.0005971125034947782,
            max=0.052005865549951,
            sse=2.0185385994152774,
        ),
    ),
    # evo_rpe tum $D/$FR2
    (
        "fr2",
        "",
        dict(
            rmse=0.003490321374787292,
            mean=0.0030380874175009644,
            median=0.002750288386204023,
            std=0.0017182456584898963,
            min=0.0001319690055884261,
            max=0.01948467892016712,
            sse=0.026472231989372496,
        ),
    ),
    # evo_rpe tum $D/$FR2 -s
    (
        "fr2",
        "-s",
        dict(
            rmse=0.0034850168908881905,
            mean=0.0030303829997873023,
            median=0.0027455208712611687,
            std=0.001721081521711306,
            min=0.00013944393314246195,
            max=0.020907743940873028,
            sse=0.02639182975180323,
        ),
    ),
    # evo_rpe tum $D/$FR2 -as -d 0.2 -u m
    (
        "fr2",
        "-as -d 0.2 -u m",
        dict(
            rmse=0.007057863511150527,
            mean=0.0063688714804944965,
            median=0.005840805260018593,
            std=0.0030415314246237694,
            min=0.0017215338978050743,
            max=0.017813495807741858,
            sse=0.004333769048756614,
        ),
    ),
    # evo_rpe tum $D/$FR2 -r full -d 30 --all_pairs
    (
        "fr2",
        "-r full -d 30 --all_pairs",
        dict(
            rmse=0.014319692854788766,
            mean=0.01297382080251712,
            median=0.01169481751489114,
            std=0.006060823148687187,
            min=0.002169636300081801,
            max=0.043824890743895506,
            sse=0.4396349258085672,
        ),
    ),
    # evo_rpe tum $D/$FR2 --align_origin -r angle_deg -d 10
    (
        "fr2",
        "--align_origin -r angle_deg -d 10",
        dict(
            rmse=0.4206447080240472,
            mean=0.3543449457998074,
            median=0.3047166914822914,
            std=0.22667516355959133,
            min=0.04205499652007823,
            max=1.4799563797025181,
            sse=38.39640757433399,
        ),
    ),
    # evo_rpe tum $D/$FR2 -u d -d 2 --pairs_from_reference
    (
        "fr2",
        "-u d -d 2 --pairs_from_reference",
        dict(
            rmse=0.0054810972057813346,
            mean=0.004749520803058714,
            median=0.0043268735350035425,
            std=0.00273577753491333,
            min=0.00044887594508055456,
            max=0.01948467892016712,
            sse=0.012647861589853284,
        ),
    ),
    # evo_rpe tum $D/$FR2 --t_offset 0.005 --t_max_diff 0.02
    (
        "fr2",
        "--t_offset 0.005 --t_max_diff 0.02",
        dict(
            rmse=0.0035767882942486203,
            mean=0.0031130347000633543,
            median=0.0028043224775505613,
            std=0.0017613714707793511,
            min=0.00028569716091457513,
            max=0.015488184949505527,
            sse=0.028465347266669546,
        ),
    ),
    # evo_rpe tum $D/$FR2 -r point_distance_error_ratio -d 20
    (
        "fr2",
        "-r point_distance_error_ratio -d 20",
        dict(
            rmse=5.555212782847111,
            mean=3.078492036526992,
            median=2.071225669760655,
            std=4.624205428367973,
            min=0.002001024985299948,
            max=40.35823983360766,
            sse=3332.9220187724572,
        ),
    ),
]


def _copy_pair(pair: str, tmp_path: Path) -> tuple[Path, Path]:
    out = []
    for name in PAIRS[pair]:
        shutil.copy(DATA / name, tmp_path / name)
        out.append(tmp_path / name)
    return out[0], out[1]


def _run_json(args: list[str], capsys: pytest.CaptureFixture[str]) -> dict:
    with pytest.raises(SystemExit) as exc:
        main(["rpe", *args, "--json"])
    assert exc.value.code in (0, None)
    return json.loads(capsys.readouterr().out)


def _assert_stats(got: dict[str, float], want: dict[str, float]) -> None:
    for key, value in want.items():
        # evo's promise is 1e-6; we hold 1e-9 (sse relative: it sums thousands of squares)
        tol = 1e-9 * max(1.0, abs(value)) if key == "sse" else 1e-9
        assert got[key] == pytest.approx(value, abs=tol), key


@needs_data
@pytest.mark.parametrize(
    ("pair", "flags", "expected"), EVO_RPE, ids=[f"{p}:{f}" for p, f, _ in EVO_RPE]
)
def test_cli_equals_evo_rpe(
    pair: str,
    flags: str,
    expected: dict[str, float],
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
) -> None:
    ref, est = _copy_pair(pair, tmp_path)
    doc = _run_json([str(ref), str(est), *flags.split()], capsys)
    _assert_stats(doc["stats"], expected)


@needs_data
def test_cli_text_output_names_relation_and_alignment(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    ref, est = _copy_pair("fr1", tmp_path)
    with pytest.raises(SystemExit):
        main(["rpe", str(ref), str(est), "-r", "angle_deg", "-as", "-d", "10"])
    out = capsys.readouterr().out
    assert "RPE w.r.t. rotation angle in degrees (deg)" in out
    assert "Sim(3)" in out and "delta = 10 (frames)" in out
    assert "rmse" in out


# (flags for uwval's rpe(), evo metric arguments) checked pair for pair against evo live
LIVE = [
    dict(relation="trans_part", delta=1, delta_unit="f"),
    dict(relation="full", delta=7, delta_unit="f", all_pairs=True),
    dict(relation="angle_deg", delta=0.05, delta_unit="m"),
    dict(relation="rot_part", delta=0.1, delta_unit="m", all_pairs=True),
    dict(relation="angle_rad", delta=2.0, delta_unit="d"),
    dict(relation="point_distance", delta=0.03, delta_unit="r", pairs_from_reference=True),
]


@needs_data
@pytest.mark.parametrize("pair", sorted(PAIRS))
@pytest.mark.parametrize("opts", LIVE, ids=lambda o: "-".join(map(str, o.values())))
def test_pairs_and_errors_equal_evo_live(pair: str, opts: dict, tmp_path: Path) -> None:
    metrics = pytest.importorskip("evo.core.metrics")
    from evo.core import sync
    from evo.tools import file_interface

    ref_p, est_p = _copy_pair(pair, tmp_path)
    t_ref = file_interface.read_tum_trajectory_file(str(ref_p))
    t_est = file_interface.read_tum_trajectory_file(str(est_p))
    a, b = sync.associate_trajectories(t_ref, t_est, max_diff=0.01)
    units = {"f": metrics.Unit.frames, "m": metrics.Unit.meters, "d": metrics.Unit.degrees}
    units["r"] = metrics.Unit.radians
    names = {
        "trans_part": metrics.PoseRelation.translation_part,
        "rot_part": metrics.PoseRelation.rotation_part,
        "full": metrics.PoseRelation.full_transformation,
        "angle_deg": metrics.PoseRelation.rotation_angle_deg,
        "angle_rad": metrics.PoseRelation.rotation_angle_rad,
        "point_distance": metrics.PoseRelation.point_distance,
    }
    m = metrics.RPE(
        names[opts["relation"]],
        opts["delta"],
        units[opts["delta_unit"]],
        0.1,
        opts.get("all_pairs", False),
        opts.get("pairs_from_reference", False),
    )
    m.process_data((a, b))
    res = rpe(read_tum(ref_p), read_tum(est_p), **opts)
    np.testing.assert_array_equal(res.second, np.asarray(m.delta_ids))
    np.testing.assert_allclose(res.errors, m.error, rtol=0, atol=1e-9)


# ----------------------------------------------------------------------- slow reference
def _mat(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    x, y, z, w = q / np.linalg.norm(q)
    r = np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )
    t = np.eye(4)
    t[:3, :3] = r
    t[:3, 3] = p
    return t


def _angle(r: np.ndarray) -> float:
    # rotation angle from the skew part and the trace (accurate at all angles)
    s = np.linalg.norm([r[2, 1] - r[1, 2], r[0, 2] - r[2, 0], r[1, 0] - r[0, 1]]) / 2
    return math.atan2(s, (np.trace(r) - 1) / 2)


def _slow_pairs(
    mats: list[np.ndarray], delta: float, unit: str, all_pairs: bool
) -> list[tuple[int, int]]:
    n = len(mats)
    if unit == "f":
        d = int(delta)
        if all_pairs:
            return [(i, i + d) for i in range(n) if i + d < n]
        ids = list(range(0, n, d))
        return list(itertools.pairwise(ids))
    if unit == "m":
        steps = [float(np.linalg.norm(mats[k + 1][:3, 3] - mats[k][:3, 3])) for k in range(n - 1)]
    else:
        steps = [_angle(mats[k][:3, :3].T @ mats[k + 1][:3, :3]) for k in range(n - 1)]
    if not all_pairs:
        ids, acc = [0], 0.0
        for k, s in enumerate(steps, start=1):
            acc += s
            if acc >= delta:
                ids.append(k)
                acc = 0.0
        return list(itertools.pairwise(ids))
    tol = 0.1 * delta
    out = []
    if unit == "m":
        cum = np.concatenate([[0.0], np.cumsum(steps)])
        for i in range(n - 1):
            e = [abs((cum[j] - cum[i]) - delta) for j in range(i + 1, n)]
            k = int(np.argmin(e))
            if e[k] <= tol:
                out.append((i, i + 1 + k))
        return out
    for i in range(n - 1):
        for j in range(i + 1, n):
            a = _angle(mats[i][:3, :3].T @ mats[j][:3, :3])
            if delta - tol <= a <= delta + tol:
                out.append((i, j))
    return out


def _slow_error(qi, qj, pi, pj, relation: str) -> float:
    if relation == "point_distance":
        return abs(np.linalg.norm(qj[:3, 3] - qi[:3, 3]) - np.linalg.norm(pj[:3, 3] - pi[:3, 3]))
    e = np.linalg.inv(np.linalg.inv(qi) @ qj) @ (np.linalg.inv(pi) @ pj)
    if relation == "trans_part":
        return float(np.linalg.norm(e[:3, 3]))
    if relation == "rot_part":
        return float(np.linalg.norm(e[:3, :3] - np.eye(3)))
    if relation == "full":
        return float(np.linalg.norm(e - np.eye(4)))
    a = _angle(e[:3, :3])
    return math.degrees(a) if relation == "angle_deg" else a


def _random_stream(rng: np.random.Generator, n: int, step: float, spin: float) -> PoseStream:
    pos = np.cumsum(rng.normal(0, step, (n, 3)), axis=0)
    rv = np.cumsum(rng.normal(0, spin, (n, 3)), axis=0)
    ang = np.linalg.norm(rv, axis=1, keepdims=True)
    axis = np.where(ang > 0, rv / np.maximum(ang, 1e-300), [[1.0, 0, 0]])
    quat = np.concatenate([axis * np.sin(ang / 2), np.cos(ang / 2)], axis=1)
    t = np.arange(n, dtype=np.int64) * 50_000_000
    return PoseStream(t, pos, quat)


@settings(max_examples=60, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    n=st.integers(3, 40),
    relation=st.sampled_from([r for r in RELATIONS if r != "point_distance_error_ratio"]),
    unit_delta=st.sampled_from(
        [("f", 1), ("f", 3), ("m", 0.3), ("m", 1.0), ("r", 0.2), ("d", 25.0)]
    ),
    all_pairs=st.booleans(),
)
def test_vectorised_equals_slow_matrix_reference(
    seed: int, n: int, relation: str, unit_delta: tuple[str, float], all_pairs: bool
) -> None:
    rng = np.random.default_rng(seed)
    ref = _random_stream(rng, n, 0.2, 0.1)
    est = PoseStream(
        ref.t,
        ref.position + rng.normal(0, 0.05, (n, 3)),
        _random_stream(rng, n, 0.2, 0.1).orientation,
    )
    unit, delta = unit_delta
    mats_r = [_mat(p, q) for p, q in zip(ref.position, ref.orientation, strict=False)]
    mats_e = [_mat(p, q) for p, q in zip(est.position, est.orientation, strict=False)]
    d_rad = math.radians(delta) if unit == "d" else delta
    want_pairs = _slow_pairs(mats_e, d_rad, "r" if unit == "d" else unit, all_pairs)
    if not want_pairs:
        with pytest.raises(AlignmentError, match="no pose pair"):
            rpe(ref, est, relation=relation, delta=delta, delta_unit=unit, all_pairs=all_pairs)
        return
    res = rpe(ref, est, relation=relation, delta=delta, delta_unit=unit, all_pairs=all_pairs)
    assert list(zip(res.first.tolist(), res.second.tolist(), strict=False)) == want_pairs
    want = [
        _slow_error(mats_r[i], mats_r[j], mats_e[i], mats_e[j], relation) for i, j in want_pairs
    ]
    np.testing.assert_allclose(res.errors, want, rtol=1e-9, atol=1e-9)
    assert res.stats["rmse"] == pytest.approx(math.sqrt(np.mean(np.square(want))), rel=1e-9)


def test_refuses_what_it_cannot_compute() -> None:
    rng = np.random.default_rng(1)
    s = _random_stream(rng, 10, 0.1, 0.1)
    with pytest.raises(Exception, match="whole number"):
        rpe(s, s, delta=1.5, delta_unit="f")
    with pytest.raises(Exception, match=r"within \[0.0, 180\]"):
        rpe(s, s, delta=200, delta_unit="d")
    with pytest.raises(Exception, match="pose-relation"):
        rpe(s, s, relation="bogus")
    with pytest.raises(AlignmentError, match="no pose pair"):
        rpe(s, s, delta=100, delta_unit="m")
    other = PoseStream(s.t[:5], s.position[:5], s.orientation[:5])
    with pytest.raises(AlignmentError, match="equal counts"):
        rpe(s, other, sync="none")
