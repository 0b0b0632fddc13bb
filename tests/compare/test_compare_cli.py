"""``uwval compare`` / ``uwval doctor`` end to end on real MCAP files and TUM text."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
from cli_runner import run_uwval

from uwval.comparison.synthetic import camera_motion, unity_view, vehicle_motion, write_pair_log
from uwval.io.tum import write_tum

AXES = ("x", "y", "z", "roll", "pitch", "yaw")


def _uwval(*args: str | Path, check: bool = True) -> subprocess.CompletedProcess[str]:
    return run_uwval(*args, check=check)


@pytest.fixture(scope="module")
def run_log(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A recorded-like run: vehicle + camera, Unity at 60 Hz with 20 ms latency, FLU map."""
    path = tmp_path_factory.mktemp("logs") / "run.mcap"
    g = vehicle_motion(1000, rate_hz=50.0, seed=21)
    cam = camera_motion(g)
    write_pair_log(
        path,
        g,
        unity_view(g, convention="unity-flu", latency=0.02),
        camera=(
            cam,
            unity_view(cam, convention="unity-flu", latency=0.02, topic="/unity/gui_camera_pose"),
        ),
    )
    return path


@pytest.fixture(scope="module")
def wrong_map_log(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The Unity script used To<ENU>() but the log says unity-flu (the classic bug)."""
    path = tmp_path_factory.mktemp("logs") / "wrong.mcap"
    g = vehicle_motion(1000, rate_hz=50.0, seed=22)
    write_pair_log(path, g, unity_view(g, convention="unity-enu"), frame_id="unity-flu")
    return path


def test_compare_json_contract_on_a_log(run_log: Path) -> None:
    doc = json.loads(_uwval("compare", run_log, "--json").stdout)
    assert doc["n_samples"] > 900
    assert set(doc["axes"]) == set(AXES)
    for ax in AXES:
        for key in (
            "mae",
            "rmse",
            "max",
            "p95",
            "bias",
            "std",
            "pearson_r",
            "pearson_p",
            "pearson_ci",
        ):
            assert key in doc["axes"][ax]
    assert set(doc["position_error_norm"]) == {"mean", "median", "std", "min", "max", "rmse", "sse"}
    # right frame: small error and strong correlation on the moving axes
    assert doc["position_error_norm"]["rmse"] < 0.05
    assert doc["axes"]["x"]["pearson_r"] > 0.99
    assert doc["axes"]["yaw"]["pearson_r"] > 0.99
    assert doc["frame"]["configured"] == "unity-flu"
    assert doc["counts"]["matched"] == doc["n_samples"]
    assert doc["latency"]["min_ms"] >= 20.0 - 1e-6
    assert doc["alignment"]["mode"] == "none"
    assert set(doc["topics"]) == {"model_rov_pose", "gui_camera_pose"}
    assert doc["topics"]["gui_camera_pose"]["n_samples"] > 900
    assert doc["warnings"] == []


def test_wrong_frame_gives_a_large_error(run_log: Path) -> None:
    right = json.loads(_uwval("compare", run_log, "--json").stdout)
    wrong = json.loads(_uwval("compare", run_log, "--frame", "unity-enu", "--json").stdout)
    assert wrong["position_error_norm"]["rmse"] > 50 * right["position_error_norm"]["rmse"]
    assert wrong["rotation_error_deg"]["rmse"] > 45.0
    assert any("fits worse than 'unity-flu'" in w for w in wrong["warnings"])


def test_doctor_names_the_real_map(wrong_map_log: Path) -> None:
    proc = _uwval("doctor", wrong_map_log, "--json")
    report = json.loads(proc.stdout)
    diag = report["model_rov_pose"]
    assert diag["configured"] == "unity-flu"
    assert diag["best"] == "unity-enu"
    assert "fits worse" in diag["warning"]
    human = _uwval("doctor", wrong_map_log).stdout
    assert "unity-enu" in human
    assert "warning" in human


def test_frame_auto_fixes_the_wrong_map(wrong_map_log: Path) -> None:
    doc = json.loads(_uwval("compare", wrong_map_log, "--frame", "auto", "--json").stdout)
    assert doc["frame"]["configured"] == "unity-enu"
    assert doc["position_error_norm"]["rmse"] < 0.05


def test_readable_table(run_log: Path) -> None:
    out = _uwval("compare", run_log).stdout
    for word in (
        "axis",
        "MAE",
        "RMSE",
        "Pearson",
        "yaw",
        "position error norm",
        "model_rov_pose",
        "gui_camera_pose",
    ):
        assert word in out


def test_two_tum_files_and_output_file(tmp_path: Path) -> None:
    g = vehicle_motion(600, seed=23)
    u = unity_view(g, convention="enu", rate_hz=30.0, clock_offset=0.0)
    write_tum(tmp_path / "a.tum", g)
    write_tum(tmp_path / "b.txt", u)
    out = tmp_path / "res.json"
    doc = json.loads(
        _uwval(
            "compare",
            tmp_path / "a.tum",
            tmp_path / "b.txt",
            "--sync",
            "nearest",
            "--max-diff",
            "0.02",
            "--json",
            "-o",
            out,
        ).stdout
    )
    assert json.loads(out.read_text()) == doc
    assert doc["sync"]["method"] == "nearest"
    assert doc["counts"]["matched"] + doc["counts"]["dropped"] == min(len(g), len(u))


def test_offset_auto_through_the_cli(tmp_path: Path) -> None:
    g = vehicle_motion(1500, seed=24)
    write_tum(tmp_path / "a.tum", g)
    write_tum(tmp_path / "b.tum", g.with_(t=g.t + 2_500_000_000))
    doc = json.loads(
        _uwval(
            "compare", tmp_path / "a.tum", tmp_path / "b.tum", "--offset", "auto", "--json"
        ).stdout
    )
    assert doc["offset"]["applied_s"] == pytest.approx(-2.5, abs=1e-4)
    assert doc["offset"]["estimate"]["uncertainty_s"] < 1e-3
    assert doc["position_error_norm"]["rmse"] < 1e-3


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["missing.mcap"], "no such file"),
        (["{a}", "--gazebo-topic", "/nope"], "no topic"),
        (["{a}", "--sync", "cubic"], "unknown sync method"),
        (["{a}", "--align", "affine"], "unknown alignment"),
        (["{a}", "--frame", "zup"], "unknown frame convention"),
        (["{a}", "--offset", "soon"], "--offset must be seconds"),
    ],
)
def test_user_errors_exit_2_without_traceback(run_log: Path, args: list[str], message: str) -> None:
    proc = _uwval("compare", *[a.format(a=run_log) for a in args], check=False)
    assert proc.returncode == 2, proc.stderr
    assert message in proc.stderr
    assert "Traceback" not in proc.stderr


def test_bad_tum_line_is_reported(tmp_path: Path) -> None:
    (tmp_path / "a.tum").write_text("1 0 0 0 0 0 0 1\n2 0 0 0 0 0 0 1\n3 0 0 0 0 0 0 1\n")
    (tmp_path / "b.tum").write_text("1 0 0 0 0 0 0 1\n2 0 0 0 0 0 1\n")
    proc = _uwval("compare", tmp_path / "a.tum", tmp_path / "b.tum", check=False)
    assert proc.returncode == 2
    assert "b.tum: line 2" in proc.stderr


def test_compare_path_imports_no_heavy_libraries(tmp_path: Path) -> None:
    g = vehicle_motion(100, seed=25)
    write_tum(tmp_path / "a.tum", g)
    write_tum(tmp_path / "b.tum", g)
    code = (
        "import sys\n"
        "from uwval.cli import main\n"
        f"try:\n    main(['compare', {str(tmp_path / 'a.tum')!r}, {str(tmp_path / 'b.tum')!r},"
        " '--sync', 'nearest', '--json'])\nexcept SystemExit:\n    pass\n"
        # pandas is the TUM reader's parser (issue 29: pandas' C reader, no C of our own)
        "heavy = [m for m in ('scipy', 'matplotlib') if m in sys.modules]\n"
        "print('HEAVY', heavy)\n"
    )
    proc = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=60
    )
    assert "HEAVY []" in proc.stdout
