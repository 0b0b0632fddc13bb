"""Issue 16 from an evo user's side: evo's spellings on ``uwval compare``, --save-errors.

Reference values come from evo 1.38.1 (D = /work/shared/data/evo, F = freiburg1_xyz):

    evo_ape tum $D/F-groundtruth.txt $D/F-rgbdslam.txt -r REL --t_max_diff 0.01 \\
        --save_results out.zip          # then: stats.json inside out.zip

and are hard-coded here: the tests do not need evo.
"""

from __future__ import annotations

import csv
import io
import json
import zipfile
from pathlib import Path

import numpy as np
import pytest
from cli_runner import run_uwval
from shared_data import EVO_DATA

from uwval.comparison import compare
from uwval.comparison.engine import ape_statistics
from uwval.io.tum import read_tum

DATA = EVO_DATA
pytestmark = pytest.mark.skipif(not DATA.is_dir(), reason="shared evo data not present")
GT = "freiburg1_xyz-groundtruth.txt"
EST = "freiburg1_xyz-rgbdslam.txt"
KEYS = ("rmse", "mean", "median", "std", "min", "max", "sse")

# evo_ape tum $D/F-groundtruth.txt $D/F-rgbdslam.txt -r <relation> --t_max_diff 0.01
EVO_APE_RELATIONS = {
    "trans_part": (0.020079418378506592, 0.01806251843069654, 0.016517756173282168,
                   0.008770887660884508, 0.0012561023047507462, 0.04328943388403233,
                   0.31649868829899996),
    "rot_part": (0.01731945729918117, 0.015575300135346339, 0.014457163008175986,
                 0.00757453806063711, 0.0006774613940260841, 0.04489528355412098,
                 0.23547142689345554),
    "full": (0.026516912406184628, 0.024777205686700287, 0.023436646782218934,
             0.009446519036990043, 0.0020616200916461045, 0.058879033147674426,
             0.5519701151924555),
    "angle_deg": (0.701693152077527, 0.631027107059953, 0.5857234388452076,
                  0.30688445680425414, 0.02744682985980395, 1.8189744203109734,
                  386.5130245429089),
    "angle_rad": (0.012246855842450135, 0.011013500687530932, 0.010222802513952526,
                  0.005356144194428551, 0.00047903755028827255, 0.031747092643981706,
                  0.11773860025021766),
    "point_distance": (0.020079418378506592, 0.01806251843069654, 0.016517756173282168,
                       0.008770887660884508, 0.0012561023047507462, 0.04328943388403233,
                       0.31649868829899996),
}  # fmt: skip
# evo_ape tum ... -r angle_deg -a --t_max_diff 0.01
EVO_ANGLE_DEG_SE3_RMSE = 2.057699602015454
EVO_ANGLE_DEG_SE3_SSE = 3323.790206925627
# evo_ape tum ... -s --t_max_diff 0.01   (scale correction alone)
EVO_SCALE_ONLY_RMSE = 0.017197598502046683
# evo_ape tum ... -a --n_to_align 100 --t_max_diff 0.01
EVO_N_TO_ALIGN_100_RMSE = 0.020597402691654682
EVO_N_TO_ALIGN_100_MAX = 0.048331698296105424
# evo_ape tum ... --t_offset 0.05 --t_max_diff 0.01   (rmse, sse)
EVO_T_OFFSET_005 = (0.024555262669026735, 0.47272136500000006)
# evo_ape tum ... -as --t_max_diff 0.01 (as in test_evo_crosscheck.py)
EVO_SIM3_RMSE = 0.013389384904168201


@pytest.fixture
def fr1(tmp_path: Path) -> tuple[Path, Path]:
    out = []
    for name in (GT, EST):
        dst = tmp_path / name
        dst.write_bytes((DATA / name).read_bytes())
        out.append(dst)
    return out[0], out[1]


def _json(*args: str | Path, cwd: Path | None = None) -> dict:
    p = run_uwval("compare", *args, "--json", cwd=cwd)
    assert p.returncode == 0, p.stderr
    return json.loads(p.stdout)


@pytest.mark.parametrize("relation", sorted(EVO_APE_RELATIONS))
def test_ape_pose_relations_equal_evo_ape(fr1: tuple[Path, Path], relation: str) -> None:
    res = compare(read_tum(fr1[0]), read_tum(fr1[1]), sync="nearest", max_diff=0.01)
    got = ape_statistics(res.reference, res.other, relation)
    for key, want in zip(KEYS, EVO_APE_RELATIONS[relation], strict=True):
        assert got[key] == pytest.approx(want, abs=1e-6, rel=1e-9), (relation, key)


def test_r_angle_deg_with_a_on_the_command_line_equals_evo(fr1: tuple[Path, Path]) -> None:
    doc = _json(*fr1, "--sync", "nearest", "--t_max_diff", "0.01", "-r", "angle_deg", "-a")
    assert doc["alignment"]["mode"] == "se3"
    ape = doc["ape"]
    assert ape["pose_relation"] == "angle_deg" and ape["unit"] == "deg"
    assert ape["rmse"] == pytest.approx(EVO_ANGLE_DEG_SE3_RMSE, abs=1e-6)
    assert ape["sse"] == pytest.approx(EVO_ANGLE_DEG_SE3_SSE, rel=1e-9)
    assert doc["topics"]["trajectory"]["ape"] == ape


def test_r_is_printed_in_the_table(fr1: tuple[Path, Path]) -> None:
    p = run_uwval("compare", *fr1, "--sync", "nearest", "--pose_relation", "trans_part")
    assert p.returncode == 0, p.stderr
    assert "APE w.r.t. trans_part [m]: rmse 0.0200794184 " in p.stdout


def test_evo_alignment_flags_and_clusters(fr1: tuple[Path, Path]) -> None:
    # -as is -a -s (Sim(3)); -va is verbose + align (se3); -s alone corrects the scale only
    sim3 = _json(*fr1, "--sync", "nearest", "-as")
    assert sim3["alignment"]["mode"] == "sim3"
    assert sim3["position_error_norm"]["rmse"] == pytest.approx(EVO_SIM3_RMSE, abs=1e-9)
    scale = _json(*fr1, "--sync", "nearest", "--correct_scale")
    assert scale["alignment"]["mode"] == "scale"
    assert scale["position_error_norm"]["rmse"] == pytest.approx(EVO_SCALE_ONLY_RMSE, abs=1e-9)
    n100 = _json(*fr1, "--sync", "nearest", "-a", "--n_to_align", "100")
    assert n100["position_error_norm"]["rmse"] == pytest.approx(EVO_N_TO_ALIGN_100_RMSE, abs=1e-9)
    assert n100["position_error_norm"]["max"] == pytest.approx(EVO_N_TO_ALIGN_100_MAX, abs=1e-9)
    shifted = _json(*fr1, "--sync", "nearest", "--t_offset", "0.05")["position_error_norm"]
    assert (shifted["rmse"], shifted["sse"]) == pytest.approx(EVO_T_OFFSET_005, abs=1e-12)
    p = run_uwval("compare", *fr1, "--sync", "nearest", "-va")
    assert p.returncode == 0, p.stderr
    assert "align se3" in p.stdout and "alignment se3: scale 1," in p.stdout


def test_evo_flags_parse_the_same_through_typer(fr1: tuple[Path, Path]) -> None:
    # typer (the only parser) reads evo's clustered short flags -as as -a -s
    from typer.testing import CliRunner

    import uwval.cli.compare_cmd  # noqa: F401  (registers the command)
    from uwval.cli import app

    args = ["compare", *map(str, fr1), "--sync", "nearest", "-as", "--t_max_diff", "0.01"]
    res = CliRunner().invoke(app, [*args, "--t_offset", "0", "--json"])
    assert res.exit_code == 0, res.output
    doc = json.loads(res.stdout)
    assert doc["alignment"]["mode"] == "sim3"
    assert doc["position_error_norm"]["rmse"] == pytest.approx(EVO_SIM3_RMSE, abs=1e-9)


def test_contradicting_alignment_options_are_one_line_errors(fr1: tuple[Path, Path]) -> None:
    folder = fr1[0].parent  # a directory: no CSV can be written there
    for args, needle in (
        (["--save-errors", str(folder)], f"{folder}: cannot write the per-sample errors"),
        (["--align", "se3", "-as"], "--align se3 contradicts -a -s"),
        (["-a", "--align_origin"], "--align_origin cannot be combined"),
        (["-r", "angle"], "unknown pose relation 'angle'; choose one of trans_part"),
        (["-a", "--n_to_align", "0"], "--n_to_align must be >= 1"),
    ):
        p = run_uwval("compare", *fr1, *args)
        assert p.returncode == 2, (args, p.stderr)
        assert needle in p.stderr and "Traceback" not in p.stderr
        assert len(p.stderr.strip().splitlines()) == 1


def test_save_results_zip_has_evos_layout_and_values(
    fr1: tuple[Path, Path], tmp_path: Path
) -> None:
    out = tmp_path / "res" / "fr1.zip"
    p = run_uwval("compare", *fr1, "--sync", "nearest", "-r", "full", "--save_results", out)
    assert p.returncode == 0, p.stderr
    assert f"wrote {out}" in p.stdout
    with zipfile.ZipFile(out) as zf:
        assert {"stats.json", "info.json", "uwval.json", "errors.csv"} <= set(zf.namelist())
        stats = json.loads(zf.read("stats.json"))
        info = json.loads(zf.read("info.json"))
        full = json.loads(zf.read("uwval.json"))
        # the arrays evo_res loads (it failed with KeyError 'np_arrays' without them)
        arrays = {
            name: np.load(io.BytesIO(zf.read(f"{name}.npy")))
            for name in ("error_array", "timestamps", "seconds_from_start", "distances",
                         "distances_from_start")
        }  # fmt: skip
    errors = arrays["error_array"]
    assert len(errors) == len(arrays["timestamps"]) == full["n_samples"]
    assert float(np.sqrt(np.mean(errors**2))) == pytest.approx(stats["rmse"], rel=1e-12)
    assert arrays["seconds_from_start"][0] == 0.0 and arrays["distances"][0] == 0.0
    for key, want in zip(KEYS, EVO_APE_RELATIONS["full"], strict=True):
        assert stats[key] == pytest.approx(want, abs=1e-6)
    assert info["title"].startswith("APE w.r.t. full") and info["ref_name"].endswith(GT)
    assert full["ape"]["pose_relation"] == "full"
    as_json = tmp_path / "fr1.json"  # any other suffix: the JSON result
    assert run_uwval("compare", *fr1, "--save_results", as_json).returncode == 0
    assert json.loads(as_json.read_text())["n_samples"] > 700


def test_save_errors_csv_one_row_per_aligned_sample(fr1: tuple[Path, Path], tmp_path: Path) -> None:
    out = tmp_path / "errors.csv"
    doc = _json(*fr1, "--sync", "nearest", "-a", "--save-errors", out)
    with out.open() as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == doc["n_samples"] == 785
    assert list(rows[0]) == [
        "t_ns", "t_s", "err_x_m", "err_y_m", "err_z_m", "err_roll_deg", "err_pitch_deg",
        "err_yaw_deg", "err_position_norm_m", "err_rotation_angle_deg",
    ]  # fmt: skip
    arr = np.array([[float(r[k]) for k in rows[0]] for r in rows])
    t_ns = np.array([int(r["t_ns"]) for r in rows])
    assert np.all(np.diff(t_ns) > 0) and abs(t_ns[0] * 1e-9 - arr[0, 1]) < 1e-6
    np.testing.assert_allclose(arr[:, 8], np.linalg.norm(arr[:, 2:5], axis=1), rtol=1e-12)
    # signed: the bias of x in the JSON is the mean of the column, the rmse that of the norm
    assert np.mean(arr[:, 2]) == pytest.approx(doc["axes"]["x"]["bias"], abs=1e-12)
    assert np.sqrt(np.mean(arr[:, 8] ** 2)) == pytest.approx(
        doc["position_error_norm"]["rmse"], rel=1e-12
    )
    assert np.sqrt(np.mean(arr[:, 9] ** 2)) == pytest.approx(
        doc["rotation_error_deg"]["rmse"], rel=1e-9
    )


def test_plot_file_names() -> None:
    from uwval.cli.compare_files import plot_targets

    assert plot_targets(["trajectory"], "trajectory", None) == [
        ("trajectory", Path("uwval_trajectory_trajectory.png"), Path("uwval_trajectory_errors.png"))
    ]
    names = ["model_rov_pose", "gui_camera_pose"]
    assert [t[1].name for t in plot_targets(names, "model_rov_pose", None)] == [
        "uwval_model_rov_pose_trajectory.png",
        "uwval_gui_camera_pose_trajectory.png",
    ]
    two = plot_targets(names, "model_rov_pose", Path("o/f.png"))
    assert two == [
        ("model_rov_pose", Path("o/f.png"), Path("o/f_errors.png")),
        (
            "gui_camera_pose",
            Path("o/f.gui_camera_pose.png"),
            Path("o/f.gui_camera_pose_errors.png"),
        ),
    ]


def test_bare_align_is_evos_se3_flag(fr1: tuple[Path, Path]) -> None:
    from uwval.cli.compare_args import evo_bare_align

    assert evo_bare_align(["a", "b", "--align"]) == ["a", "b", "-a"]
    assert evo_bare_align(["--align", "sim3", "--align", "--json"]) == [
        "--align",
        "sim3",
        "-a",
        "--json",
    ]
    doc = _json(*fr1, "--align", "--sync", "nearest")
    assert doc["alignment"]["mode"] == "se3"
    assert doc["position_error_norm"]["rmse"] == pytest.approx(0.013470088849733684, abs=1e-9)


def test_save_plot_names_the_trajectory_png(fr1: tuple[Path, Path], tmp_path: Path) -> None:
    target = tmp_path / "figs" / "fr1.png"
    p = run_uwval("compare", *fr1, "--save_plot", target, "--json")
    assert p.returncode == 0, p.stderr
    assert json.loads(p.stdout)["n_samples"] > 0  # stdout stays pure JSON
    for png in (target, target.with_name("fr1_errors.png")):
        assert png.read_bytes()[:4] == b"\x89PNG"
        assert f"wrote {png}" in p.stderr
    pdf = tmp_path / "figs" / "fr1.pdf"  # a format matplotlib writes is kept, as in evo
    p = run_uwval("compare", *fr1, "--save_plot", pdf)
    assert p.returncode == 0, p.stderr
    for name in ("fr1.pdf", "fr1_errors.pdf", "fr1_histogram.pdf", "fr1_errormap.pdf"):
        assert (tmp_path / "figs" / name).read_bytes()[:5] == b"%PDF-"


def test_scale_then_origin_as_evo_ape(fr1: tuple[Path, Path]) -> None:
    """evo_ape accepts -s with --align_origin: it corrects the scale, then aligns the origin.
    evo_ape tum $D/freiburg1_xyz-groundtruth.txt $D/freiburg1_xyz-rgbdslam.txt -s
        --align_origin --save_results so.zip  ->  stats.json:"""
    evo = {"rmse": 0.020089785798976224, "mean": 0.018124526095164708,
           "median": 0.016799455903821085, "std": 0.008666086041255319,
           "max": 0.042897529375583256, "sse": 0.3168256023572662}  # fmt: skip
    p = run_uwval("compare", *fr1, "-s", "--align_origin", "--t_max_diff", "0.01", "--json")
    assert p.returncode == 0, p.stderr
    doc = json.loads(p.stdout)
    assert doc["alignment"]["mode"] == "scale_origin"
    for key, want in evo.items():
        assert doc["position_error_norm"][key] == pytest.approx(want, abs=1e-9), key
