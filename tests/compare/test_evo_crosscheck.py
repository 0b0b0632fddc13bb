"""uwval's numbers equal evo 1.38.1's on the TUM RGB-D pairs (issue 3 item 8).

Expected values were produced with evo 1.38.1 by (D = /work/shared/data/evo):

    evo_ape tum $D/<ref> $D/<est> [-a | -as | --align_origin] --t_max_diff 0.01 \\
        --save_results out.zip          # then: stats.json inside out.zip

and are hard-coded here, so the test does not depend on evo being installed.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from uwval.comparison import compare
from uwval.io.tum import read_tum

DATA = Path(__file__).resolve().parents[3] / "shared" / "data" / "evo"

# evo_ape tum freiburg1_xyz-groundtruth.txt freiburg1_xyz-rgbdslam.txt <flags> --t_max_diff 0.01
FR1 = {
    "none": dict(
        rmse=0.020079418378506592,
        mean=0.01806251843069654,
        median=0.016517756173282164,
        std=0.008770887660884508,
        min=0.0012561023047507462,
        max=0.04328943388403233,
        sse=0.31649868829899996,
    ),
    # -a
    "se3": dict(
        rmse=0.013470088849733684,
        mean=0.012024498709110237,
        median=0.011183186775061079,
        std=0.0060708092058905936,
        min=0.0009550461813175756,
        max=0.03475954589500906,
        sse=0.14243298549147998,
    ),
    # -as
    "sim3": dict(
        rmse=0.013389384904168201,
        mean=0.011986889624888909,
        median=0.011133899090810936,
        std=0.005965744315062285,
        min=0.000732706705229249,
        max=0.034846144852261104,
        sse=0.14073136806789432,
    ),
    # --align_origin
    "origin": dict(
        rmse=0.0193679199417015,
        mean=0.017348899180007264,
        median=0.01586610065781946,
        std=0.008609995360631843,
        min=3.1401849173675503e-16,
        max=0.04217667886684081,
        sse=0.29446631345150454,
    ),
}

# evo_ape tum fr2_desk_groundtruth.txt fr2_desk_ORB.txt <flags> --t_max_diff 0.01
FR2 = {
    "none": dict(
        rmse=3.17399354190223,
        mean=2.9496938875994747,
        median=2.594642464975095,
        std=1.1719816438389132,
        min=1.4603442833644174,
        max=5.066735062280106,
        sse=21901.386898776575,
    ),
    "se3": dict(
        rmse=0.008118977562044926,
        mean=0.0074917768702161495,
        median=0.007414629829316952,
        std=0.00312906950703932,
        min=0.0003496361984068482,
        max=0.024299593694385276,
        sse=0.14330528992359803,
    ),
    "sim3": dict(
        rmse=0.006123163030157264,
        mean=0.00558619731870614,
        median=0.005305225075852613,
        std=0.002507493770752984,
        min=0.0001897958096088303,
        max=0.021476785562788304,
        sse=0.08151005482370531,
    ),
    "origin": dict(
        rmse=0.042015511713436704,
        mean=0.034069931767972746,
        median=0.028488955204609347,
        std=0.024587455620043695,
        min=0.0,
        max=0.08431421697474216,
        sse=3.8377692101541707,
    ),
}

PAIRS = {
    "fr1": ("freiburg1_xyz-groundtruth.txt", "freiburg1_xyz-rgbdslam.txt", FR1),
    "fr2": ("fr2_desk_groundtruth.txt", "fr2_desk_ORB.txt", FR2),
}

needs_data = pytest.mark.skipif(not DATA.is_dir(), reason="shared evo data not present")


def _assert_stats(got: dict[str, float], want: dict[str, float]) -> None:
    for key, value in want.items():
        # sse sums ~800-2900 squared errors: compare relatively; the rest absolutely
        tol = 1e-9 * max(1.0, abs(value)) if key == "sse" else 1e-9
        assert got[key] == pytest.approx(value, abs=tol), key


@needs_data
@pytest.mark.parametrize("pair", sorted(PAIRS))
@pytest.mark.parametrize("align", ["none", "se3", "sim3", "origin"])
def test_position_error_norm_equals_evo(pair: str, align: str) -> None:
    ref_name, est_name, expected = PAIRS[pair]
    ref = read_tum(DATA / ref_name)
    est = read_tum(DATA / est_name)
    res = compare(ref, est, sync="nearest", max_diff=0.01, align=align)
    _assert_stats(res.stats["position_error_norm"], expected[align])


# evo_ape tum freiburg1_xyz-groundtruth.txt freiburg1_xyz-rgbdslam.txt -r angle_deg \
#     --t_max_diff 0.01 [-a]      (evo's APE of the rotation angle, degrees)
FR1_ROTATION_DEG = {
    "none": dict(
        rmse=0.701693152077527,
        mean=0.631027107059953,
        median=0.5857234388452076,
        std=0.30688445680425425,
        min=0.02744682985980395,
        max=1.818974420310976,
        sse=386.51302454290897,
    ),
    # -a
    "se3": dict(
        rmse=2.057699602015445,
        mean=2.024695481920092,
        median=2.0008410866935913,
        std=0.3670638331773981,
        min=0.7419583981755085,
        max=3.639590831308399,
        sse=3323.7902069255983,
    ),
}


@needs_data
@pytest.mark.parametrize("align", sorted(FR1_ROTATION_DEG))
def test_rotation_angle_equals_evo(align: str) -> None:
    # the smallest angle (0.027 deg) is where an arccos formula would lose half its digits
    ref = read_tum(DATA / "freiburg1_xyz-groundtruth.txt")
    est = read_tum(DATA / "freiburg1_xyz-rgbdslam.txt")
    res = compare(ref, est, sync="nearest", max_diff=0.01, align=align)
    _assert_stats(res.stats["rotation_error_deg"], FR1_ROTATION_DEG[align])


@needs_data
def test_matched_pairs_equal_evo_association() -> None:
    """Same pose pairs as evo's associate_trajectories (run live when evo is importable)."""
    evo_sync = pytest.importorskip("evo.core.sync")
    from evo.tools import file_interface

    ref_path = DATA / "freiburg1_xyz-groundtruth.txt"
    est_path = DATA / "freiburg1_xyz-rgbdslam.txt"
    t_ref = file_interface.read_tum_trajectory_file(str(ref_path))
    t_est = file_interface.read_tum_trajectory_file(str(est_path))
    a, b = evo_sync.associate_trajectories(t_ref, t_est, max_diff=0.01)
    res = compare(read_tum(ref_path), read_tum(est_path), sync="nearest", max_diff=0.01)
    assert res.n_samples == a.num_poses == 785
    np.testing.assert_array_equal(res.reference.position, a.positions_xyz)
    np.testing.assert_array_equal(res.other.position, b.positions_xyz)


@needs_data
def test_cli_json_carries_evo_numbers() -> None:
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "uwval",
            "compare",
            str(DATA / "freiburg1_xyz-groundtruth.txt"),
            str(DATA / "freiburg1_xyz-rgbdslam.txt"),
            "--sync",
            "nearest",
            "--max-diff",
            "0.01",
            "--align",
            "sim3",
            "--json",
        ],
        capture_output=True,
        text=True,
        check=True,
        timeout=60,
    )
    doc = json.loads(proc.stdout)
    assert doc["n_samples"] == 785
    _assert_stats(doc["position_error_norm"], FR1["sim3"])
    assert doc["alignment"]["mode"] == "sim3"
    assert doc["alignment"]["scale"] == pytest.approx(1.0, abs=0.05)
