"""What the user types wins (review of issues 16/17): a pair's frame in uwval.toml does not
override --frame; an explicit option equal to its default (--offset 0) is still given on
typer's path; evo's --t_max_diff means evo's nearest association; --batch refuses --config."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

from cli_runner import run_uwval


def _log(tmp_path: Path) -> Path:
    log = tmp_path / "run.mcap"
    run_uwval(
        "simulate",
        "--duration",
        "2",
        "--force",
        "20,5,0",
        "--torque",
        "0,0,2",
        "-o",
        log,
        check=True,
    )
    return log


def test_frame_on_the_command_line_beats_the_project_files_pair_frame(tmp_path: Path) -> None:
    log = _log(tmp_path)
    (tmp_path / "uwval.toml").write_text(
        '[[pair]]\nname = "rov"\nreference = "/gazebo/model_rov_pose"\n'
        'other = "/unity/model_rov_pose"\nframe = "enu"\n'
    )
    wrong = json.loads(run_uwval("compare", log, "--json", cwd=tmp_path, check=True).stdout)
    right = json.loads(
        run_uwval("compare", log, "--frame", "unity-flu", "--json", cwd=tmp_path).stdout
    )
    assert wrong["frame"]["configured"] == "enu"  # the file's pair frame, nothing given
    assert right["frame"]["configured"] == "unity-flu"
    assert right["position_error_norm"]["rmse"] < 0.05
    assert wrong["position_error_norm"]["rmse"] > 10 * right["position_error_norm"]["rmse"]


def test_t_max_diff_means_nearest_association_as_in_evo(shared_data: Path, tmp_path: Path) -> None:
    gt = shutil.copy(shared_data / "evo" / "freiburg1_xyz-groundtruth.txt", tmp_path)
    est = shutil.copy(shared_data / "evo" / "freiburg1_xyz-rgbdslam.txt", tmp_path)
    out = run_uwval("compare", gt, est, "--t_max_diff", "0.01", "--json")
    assert out.returncode == 0, out.stderr
    doc = json.loads(out.stdout)
    assert doc["sync"]["method"] == "nearest"
    # evo_ape tum freiburg1_xyz-groundtruth.txt freiburg1_xyz-rgbdslam.txt --t_max_diff 0.01
    assert abs(doc["position_error_norm"]["rmse"] - 0.020079418378506592) < 1e-9


def test_an_explicit_offset_equal_to_the_default_is_still_given(tmp_path: Path) -> None:
    log = _log(tmp_path)
    (tmp_path / "uwval.toml").write_text('[compare]\noffset = "auto"\n')
    # "-vr trans_part" is clustered: typer's path, where given values were once compared
    # with the defaults (so --offset 0 fell back to the file's "auto")
    out = run_uwval("compare", log, "--offset", "0", "-vr", "trans_part", "--json", cwd=tmp_path)
    assert out.returncode == 0, out.stderr
    assert json.loads(out.stdout)["offset"]["source"] == "argument"
    out = run_uwval("compare", log, "--json", cwd=tmp_path)
    assert json.loads(out.stdout)["offset"]["source"] == "auto"


def test_batch_refuses_a_project_file(tmp_path: Path) -> None:
    _log(tmp_path)
    cfg = tmp_path / "c.toml"
    cfg.write_text('[compare]\nsync = "bogus"\n')
    out = run_uwval("compare", tmp_path, "--batch", "--config", cfg)
    assert out.returncode == 2
    assert "--config applies to one comparison" in out.stderr
    assert "Traceback" not in out.stderr


def test_evo_flags_beat_the_project_files_align(shared_data: Path, tmp_path: Path) -> None:
    gt = shutil.copy(shared_data / "evo" / "freiburg1_xyz-groundtruth.txt", tmp_path)
    est = shutil.copy(shared_data / "evo" / "freiburg1_xyz-rgbdslam.txt", tmp_path)
    (tmp_path / "uwval.toml").write_text('[compare]\nalign = "sim3"\n')
    out = run_uwval("compare", gt, est, "--align_origin", "--json", cwd=tmp_path)
    assert out.returncode == 0, out.stderr  # was: "--align sim3 contradicts --align_origin"
    assert json.loads(out.stdout)["alignment"]["mode"] == "origin"


def test_report_and_check_read_t_max_diff_as_compare_does() -> None:
    """report/check take compare's options through one helper: a max diff given without a
    sync method means evo's nearest association there too; an explicit --sync wins."""
    from uwval.cli.report_cmd import _compare_opts

    given = _compare_opts({"max_diff": 0.01})
    assert given["sync"] == "nearest" and given["max_diff"] == 0.01
    explicit = _compare_opts({"sync": "interp", "max_diff": 0.01})
    assert explicit["sync"] == "interp"
    assert "sync" not in _compare_opts({})
