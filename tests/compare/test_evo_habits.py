"""Issue 33 point 2 through the command line: evo's habits give evo's numbers.

Each expected value was made with evo 1.38.1 here, by the command written beside it
(D=/work/shared/data/evo; the numbers are stats.json of the --save_results zip), and is
hard-coded so that the tests do not need evo installed:

    evo_ape tum $D/freiburg1_xyz-groundtruth.txt $D/freiburg1_xyz-rgbdslam.txt [ARGS] \\
        --save_results out.zip --no_warnings
"""

from __future__ import annotations

import json
import shutil
import zipfile
from pathlib import Path
from typing import Any

import pytest
from cli_runner import run_uwval

GT, EST = "freiburg1_xyz-groundtruth.txt", "freiburg1_xyz-rgbdslam.txt"

#: evo_ape tum GT EST (no options): evo's nearest association, max diff 0.01 s
PLAIN = {"rmse": 0.020079418378506592, "mean": 0.01806251843069654, "max": 0.04328943388403233}
#: evo_ape tum $D/fr2_desk_groundtruth.txt $D/fr2_desk_ORB.txt
FR2 = {"rmse": 3.17399354190223, "mean": 2.9496938875994747, "max": 5.066735062280106}
#: evo_ape tum GT EST --t_start 1305031100 --t_end 1305031120
WINDOW = {"rmse": 0.01883226296062088, "mean": 0.01665420354615042, "sse": 0.18548410905799995}
#: evo_ape tum GT EST --downsample 200
DOWNSAMPLED = {
    "rmse": 0.020828755106622836,
    "min": 0.006261734104862681,
    "sse": 0.010412088943000004,
}
#: evo_ape tum GT EST -r trans_part --change_unit mm
MILLIMETRES = {"rmse": 20.079418378506592, "median": 16.51775617328217, "sse": 316498.688299}
#: evo_ape tum GT EST -r angle_deg --change_unit rad
RADIANS = {"rmse": 0.012246855842450135, "mean": 0.011013500687530932, "max": 0.031747092643981706}
#: evo_ape tum GT EST -as --t_start 1305031100
SIM3_FROM = {"rmse": 0.013389384904168217, "mean": 0.011986889624888907, "max": 0.03484614485226119}
#: evo_ape tum GT EST --t_offset 0.005 --t_max_diff 0.02
OFFSET = {"rmse": 0.020012478031323316, "mean": 0.01794419781528207, "max": 0.04284335054591326}
#: evo_rpe tum GT EST --t_start 1305031100 --t_end 1305031120
RPE_WINDOW = {"rmse": 0.0063884250281753705, "max": 0.020865814532329833}
#: evo_rpe tum GT EST -d 10 -u f --downsample 300
RPE_DOWNSAMPLED = {"rmse": 0.024795062998031143, "min": 0.018811588427434668}


@pytest.fixture
def evo_dir(shared_data: Path, tmp_path: Path) -> Path:
    """Copies of evo's TUM example pairs (the shared data is read-only)."""
    for name in (GT, EST, "fr2_desk_groundtruth.txt", "fr2_desk_ORB.txt"):
        shutil.copyfile(shared_data / "evo" / name, tmp_path / name)
    return tmp_path


def _json(*args: Any) -> dict[str, Any]:
    p = run_uwval("compare", *args, "--json")
    assert p.returncode == 0, p.stderr
    doc: dict[str, Any] = json.loads(p.stdout)
    return doc


def _close(stats: dict[str, Any], expected: dict[str, float]) -> None:
    for key, value in expected.items():
        assert stats[key] == pytest.approx(value, rel=1e-12), key


def test_two_tum_files_compare_as_evo_ape_by_default(evo_dir: Path) -> None:
    doc = _json(evo_dir / GT, evo_dir / EST)
    assert doc["sync"]["method"] == "nearest" and doc["sync"]["max_diff_s"] == 0.01
    _close(doc["position_error_norm"], PLAIN)
    fr2 = _json(evo_dir / "fr2_desk_groundtruth.txt", evo_dir / "fr2_desk_ORB.txt")
    _close(fr2["position_error_norm"], FR2)
    # interpolation only when asked for: another number (0.019907, not evo's 0.020079)
    interp = _json(evo_dir / GT, evo_dir / EST, "--sync", "interp")
    assert interp["sync"]["method"] == "interp"
    assert interp["position_error_norm"]["rmse"] == pytest.approx(0.019907, abs=1e-6)


def test_the_table_says_the_association_is_evos(evo_dir: Path) -> None:
    p = run_uwval("compare", evo_dir / GT, evo_dir / EST)
    assert p.returncode == 0, p.stderr
    assert "(sync nearest, max diff 0.01 s, as evo)" in p.stdout


@pytest.mark.parametrize("word", ["tum", "kitti", "euroc", "bag", "bag2"])
def test_evos_positional_shapes(evo_dir: Path, word: str) -> None:
    if word == "tum":
        _close(_json("tum", evo_dir / GT, evo_dir / EST)["position_error_norm"], PLAIN)
        return
    # wrong counts are answered with the command to type, in one line
    p = run_uwval("compare", word, evo_dir / GT)
    assert p.returncode == 2
    assert "type uwval compare" in p.stderr and "Traceback" not in p.stderr
    assert len(p.stderr.strip().splitlines()) == 1


def test_a_log_and_two_topics(shared_data: Path, tmp_path: Path) -> None:
    log = tmp_path / "nav2.mcap"
    shutil.copyfile(shared_data / "evo" / "nav2_turtlebot.mcap", log)
    by_words = _json(log, "/odom", "/tf#base_link")
    by_bag2 = _json("bag2", log, "/odom", "/tf#base_link")
    by_flags = _json(log, "--gazebo-topic", "/odom", "--unity-topic", "/tf#base_link")
    assert by_words["n_samples"] == by_flags["n_samples"] == by_bag2["n_samples"] == 2639
    assert by_words["position_error_norm"] == by_flags["position_error_norm"]
    twice = run_uwval("compare", log, "/odom", "/amcl_pose", "--gazebo-topic", "/odom")
    assert twice.returncode == 2 and "topics given twice" in twice.stderr


@pytest.mark.parametrize(
    ("args", "expected", "section"),
    [
        (["--t_start", "1305031100", "--t_end", "1305031120"], WINDOW, "position_error_norm"),
        (["--downsample", "200"], DOWNSAMPLED, "position_error_norm"),
        (["-r", "trans_part", "--change_unit", "mm"], MILLIMETRES, "ape"),
        (["--change_unit", "mm"], MILLIMETRES, "ape"),  # evo's default relation: trans_part
        (["-r", "angle_deg", "--change_unit", "rad"], RADIANS, "ape"),
        (["-as", "--t_start", "1305031100"], SIM3_FROM, "position_error_norm"),
        (["--t_offset", "0.005", "--t_max_diff", "0.02"], OFFSET, "position_error_norm"),
    ],
)
def test_evo_ape_options_give_evos_numbers(
    evo_dir: Path, args: list[str], expected: dict[str, float], section: str
) -> None:
    doc = _json(evo_dir / GT, evo_dir / EST, *args)
    _close(doc[section], expected)


def test_change_unit_to_another_kind_is_refused_as_evo(evo_dir: Path) -> None:
    p = run_uwval("compare", evo_dir / GT, evo_dir / EST, "--change_unit", "deg")
    assert p.returncode == 2
    assert "cannot be given in deg" in p.stderr


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        (["--project_to_plane", "xy"], "evo_traj tum REF EST --project_to_plane xy --save_as_tum"),
        (["--motion_filter", "0.1", "5"], "evo_traj tum REF EST --motion_filter"),
        (["--plot_mode", "yz"], "use evo_traj --plot_mode"),
        (["--sync_method", "interpolation"], "use --sync interp or --sync nearest"),
    ],
)
def test_evo_options_uwval_does_not_compute_are_refused_with_what_to_use(
    evo_dir: Path, args: list[str], needle: str
) -> None:
    p = run_uwval("compare", evo_dir / GT, evo_dir / EST, *args)
    assert p.returncode == 2, p.stdout
    assert needle in p.stderr and "Traceback" not in p.stderr


def test_silent_logfile_no_warnings_and_plot_mode(evo_dir: Path) -> None:
    log = evo_dir / "out.log"
    p = run_uwval(
        "compare",
        evo_dir / GT,
        evo_dir / EST,
        "--silent",
        "--no_warnings",
        "--logfile",
        log,
        "--plot_mode",
        "xy",
    )
    assert p.returncode == 0, p.stderr
    assert p.stdout == ""
    text = log.read_text()
    assert "position error norm [m]: rmse 0.02007941838" in text


def test_sync_method_nearest_time_is_evos_association(evo_dir: Path) -> None:
    doc = _json(evo_dir / GT, evo_dir / EST, "--sync_method", "nearest_time")
    _close(doc["position_error_norm"], PLAIN)


def test_save_results_is_evos_only_when_the_numbers_are(evo_dir: Path) -> None:
    same = evo_dir / "same.zip"
    p = run_uwval("compare", evo_dir / GT, evo_dir / EST, "--save_results", same)
    assert p.returncode == 0, p.stderr
    with zipfile.ZipFile(same) as zf:
        assert {"stats.json", "info.json"} <= set(zf.namelist())
        _close(json.loads(zf.read("stats.json")), PLAIN)
    other = evo_dir / "interp.zip"
    q = run_uwval(
        "compare", evo_dir / GT, evo_dir / EST, "--sync", "interp", "--save_results", other
    )
    assert q.returncode == 0, q.stderr
    assert "is not an evo result (sync interp" in q.stderr
    with zipfile.ZipFile(other) as zf:
        names = set(zf.namelist())
    # evo_res loads a zip only with both files (evo.tools.file_interface.load_res_file)
    assert not {"stats.json", "info.json"} & names
    assert "uwval_stats.json" in names


def test_evo_res_refuses_the_zip_whose_numbers_differ(evo_dir: Path) -> None:
    file_interface = pytest.importorskip("evo.tools.file_interface")
    zpath = evo_dir / "interp.zip"
    run_uwval("compare", evo_dir / GT, evo_dir / EST, "--sync", "interp", "--save_results", zpath)
    with pytest.raises(file_interface.FileInterfaceException, match="not a valid result file"):
        file_interface.load_res_file(zpath)
    good = evo_dir / "nearest.zip"
    run_uwval("compare", evo_dir / GT, evo_dir / EST, "--save_results", good)
    assert file_interface.load_res_file(good).stats["rmse"] == pytest.approx(PLAIN["rmse"])


@pytest.mark.parametrize(
    ("args", "expected"),
    [
        (["--t_start", "1305031100", "--t_end", "1305031120"], RPE_WINDOW),
        (["-d", "10", "-u", "f", "--downsample", "300"], RPE_DOWNSAMPLED),
    ],
)
def test_rpe_takes_evo_rpes_options(
    evo_dir: Path, args: list[str], expected: dict[str, float]
) -> None:
    p = run_uwval("rpe", "tum", evo_dir / GT, evo_dir / EST, *args, "--json")
    assert p.returncode == 0, p.stderr
    _close(json.loads(p.stdout)["stats"], expected)


def test_rpe_save_results_plot_and_verbose(evo_dir: Path) -> None:
    zpath, png = evo_dir / "rpe.zip", evo_dir / "rpe.png"
    p = run_uwval(
        "rpe",
        evo_dir / GT,
        evo_dir / EST,
        "-as",
        "-v",
        "--save_results",
        zpath,
        "--save_plot",
        png,
    )
    assert p.returncode == 0, p.stderr
    assert "alignment sim3: scale" in p.stdout
    assert png.stat().st_size > 1000
    with zipfile.ZipFile(zpath) as zf:
        stats = json.loads(zf.read("stats.json"))
    doc = json.loads(run_uwval("rpe", evo_dir / GT, evo_dir / EST, "-as", "--json").stdout)
    assert stats == {k: doc["stats"][k] for k in stats}


def _kitti_pair(folder: Path) -> tuple[Path, Path]:
    """Two KITTI pose files (3 x 4 matrices, one a line), seeded: the reference and a noisy
    copy. evo's numbers below were made from exactly these files (np.savetxt, '%.18e')."""
    import numpy as np
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(1)
    n = 100
    pos = np.cumsum(rng.normal(0, 0.1, (n, 3)), 0)
    rot = Rotation.from_euler("z", np.linspace(0, 1, n)[:, None]).as_matrix()
    paths = []
    for name, noise in (("a.kitti", 0.0), ("b.kitti", 0.01)):
        moved = pos + noise * rng.normal(size=(n, 3))
        np.savetxt(folder / name, np.concatenate([rot, moved[:, :, None]], axis=2).reshape(n, 12))
        paths.append(folder / name)
    return paths[0], paths[1]


def test_kitti_shape_pairs_by_index_as_evo(tmp_path: Path) -> None:
    a, b = _kitti_pair(tmp_path)
    # evo_ape kitti a.kitti b.kitti --save_results k.zip  ->  stats.json rmse
    doc = _json("kitti", a, b)
    assert doc["n_samples"] == 100
    assert doc["position_error_norm"]["rmse"] == pytest.approx(0.018439118510730025, rel=1e-12)
    # evo_rpe kitti a.kitti b.kitti  ->  rmse 0.026305 (printed with 6 decimals)
    p = run_uwval("rpe", "kitti", a, b, "--json")
    assert p.returncode == 0, p.stderr
    assert json.loads(p.stdout)["stats"]["rmse"] == pytest.approx(0.026305, abs=5e-7)


def test_p_writes_the_figures_here(evo_dir: Path) -> None:
    p = run_uwval("compare", GT, EST, "-p", cwd=evo_dir)
    assert p.returncode == 0, p.stderr
    for kind in ("trajectory", "errors", "histogram", "errormap"):
        png = evo_dir / f"uwval_trajectory_{kind}.png"
        assert png.read_bytes()[:4] == b"\x89PNG"
        assert f"wrote {png.name}" in p.stdout


def test_rpe_takes_evos_bag_shape(shared_data: Path, tmp_path: Path) -> None:
    log = tmp_path / "nav2.mcap"
    shutil.copyfile(shared_data / "evo" / "nav2_turtlebot.mcap", log)
    # /tf#base_link is odom->base_link, /odom's own pose: every relative error is ~0
    p = run_uwval("rpe", "bag2", log, "/odom", "/tf#base_link", "--json")
    assert p.returncode == 0, p.stderr
    doc = json.loads(p.stdout)
    assert doc["n_pairs"] > 2000 and doc["stats"]["max"] < 1e-9
