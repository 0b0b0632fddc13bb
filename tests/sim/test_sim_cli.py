"""``uwval simulate`` options end to end through the CLI: each option must visibly have its effect
in the log, in ``uwval compare --json`` or in the run record (``--json``); bad input is one
clean line (exit 2, no traceback) naming the file or the parameter."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from cli_runner import compare_json
from cli_runner import run_uwval as uwval

from uwval.cli import main
from uwval.io import read_stream

REPO = Path(__file__).resolve().parents[2]
DURATION = "3"
MOTION = ("--force", "10,0,0", "--torque", "0,0,1", "--current", "0,0.2,0")
#: Each option's own effect is measured against the exact Unity side (no link delay, fixed
#: frames, float64, no drift); simulate's realistic defaults (real-endpoint link, vsync
#: stalls, float32, 20 ppm) are checked in tests/test_unity_model.py.
IDEAL = ("--transport", "ideal", "--frame-model", "fixed", "--no-float32")
IDEAL += ("--unity-clock-drift", "0")

#: name -> extra simulate options; all runs share MOTION and the seed.
VARIANTS: dict[str, tuple[str, ...]] = {
    "base": (),
    "latency": ("--latency", "0.05"),
    "drop": ("--drop", "0.3"),
    "jitter": ("--jitter", "0.004"),
    "offset": ("--unity-clock-offset", "0.2"),
    "enu": ("--unity-map", "unity-enu"),
    "realtime": ("--realtime",),
}


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, tuple[Path, dict[str, Any]]]:
    """Every variant simulated once (in parallel): name -> (log, run record from --json)."""
    d = tmp_path_factory.mktemp("simcli")
    procs = {
        name: subprocess.Popen(
            [
                sys.executable,
                "-m",
                "uwval",
                "simulate",
                *MOTION,
                *IDEAL,
                "--duration",
                DURATION,
                "--json",
                "-o",
                str(d / f"{name}.mcap"),
                *opts,
            ],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            stdin=subprocess.DEVNULL,
        )
        for name, opts in VARIANTS.items()
    }
    out = {}
    for name, p in procs.items():
        stdout, stderr = p.communicate(timeout=120)
        assert p.returncode == 0, f"{name}: {stderr}"
        out[name] = (d / f"{name}.mcap", json.loads(stdout))
    return out


def test_record_says_what_ran(runs: dict[str, tuple[Path, dict[str, Any]]]) -> None:
    log, rec = runs["base"]
    assert rec["log"] == str(log) and log.is_file()
    # one-axis vectors keep their component (the current is on world y)
    assert rec["factors"] == {"force": 10.0, "torque": 1.0, "current": 0.2}
    b = rec["bridge"]
    assert b["sent"] == 2 * (3 * 50 + 1)  # two topics at 50 Hz, both ends included
    assert b["received"] == b["delivered"] == b["sent"]
    assert b["dropped"] == b["server_dropped"] == b["lost_disconnected"] == 0
    assert rec["session"]["unity_map"] == "unity-flu"


def test_latency_adds_to_the_measured_latency(runs: dict[str, tuple[Path, dict[str, Any]]]) -> None:
    base = compare_json(str(runs["base"][0]))["latency"]
    late = compare_json(str(runs["latency"][0]))["latency"]
    assert late["mean_ms"] - base["mean_ms"] == pytest.approx(50.0, abs=1.0)
    assert late["min_ms"] == pytest.approx(50.0, abs=0.5)
    assert runs["latency"][1]["bridge"]["latency_mean_s"] == pytest.approx(0.05, abs=1e-6)


def test_drop_loses_about_that_share_and_is_counted(
    runs: dict[str, tuple[Path, dict[str, Any]]],
) -> None:
    b = runs["drop"][1]["bridge"]
    assert b["dropped"] / b["sent"] == pytest.approx(0.3, abs=0.08)
    assert b["sent"] == b["delivered"] + b["dropped"]
    # fewer fresh poses reach the scene: the applied stamps lag more on average
    assert b["render_lag_mean_s"] > runs["base"][1]["bridge"]["render_lag_mean_s"] + 1e-3


def test_jitter_makes_render_frames_irregular(runs: dict[str, tuple[Path, dict[str, Any]]]) -> None:
    def frame_period_std(name: str) -> float:
        s = read_stream(runs[name][0], "/unity/model_rov_pose")
        return float(np.diff(s.t).std()) * 1e-9

    assert frame_period_std("base") < 1e-6
    assert frame_period_std("jitter") > 2e-3


def test_unity_clock_offset_shifts_unity_stamps(
    runs: dict[str, tuple[Path, dict[str, Any]]],
) -> None:
    log = str(runs["offset"][0])
    shifted = compare_json(log)["latency"]
    assert shifted["min_ms"] == pytest.approx(200.0, abs=0.5)
    # telling compare the known clock offset takes it out again
    corrected = compare_json(log, "--offset", "-0.2")
    base = compare_json(str(runs["base"][0]))
    assert corrected["latency"]["mean_ms"] == pytest.approx(base["latency"]["mean_ms"], abs=0.5)
    assert corrected["position_error_norm"]["rmse"] == pytest.approx(
        base["position_error_norm"]["rmse"], rel=0.2
    )
    u = read_stream(log, "/unity/model_rov_pose")
    g = read_stream(log, "/gazebo/model_rov_pose")
    assert (u.t[0] - g.t[0]) * 1e-9 == pytest.approx(0.2, abs=1e-6)


def test_unity_enu_map_is_read_from_frame_id(runs: dict[str, tuple[Path, dict[str, Any]]]) -> None:
    log = str(runs["enu"][0])
    right = compare_json(log)
    assert right["other"]["frame"] == "unity-enu"
    base = compare_json(str(runs["base"][0]))
    assert right["position_error_norm"]["rmse"] == pytest.approx(
        base["position_error_norm"]["rmse"], rel=1e-6
    )
    assert right["axes"]["x"]["pearson_r"] > 0.99
    # the same log read with the other Unity map is badly off
    wrong = compare_json(log, "--frame", "unity-flu")
    assert wrong["position_error_norm"]["rmse"] > 0.1
    assert wrong["position_error_norm"]["rmse"] > 50 * right["position_error_norm"]["rmse"]
    # and the poses really are different numbers in the two logs
    u_enu = read_stream(log, "/unity/model_rov_pose")
    u_flu = read_stream(runs["base"][0], "/unity/model_rov_pose")
    assert np.abs(u_enu.position - u_flu.position).max() > 0.5


def test_realtime_paces_the_run_to_the_wall_clock(
    runs: dict[str, tuple[Path, dict[str, Any]]],
) -> None:
    rt = runs["realtime"][1]["bridge"]
    assert rt["wall_time_s"] >= 0.95 * float(DURATION)
    # pacing changes nothing that is logged
    assert (
        compare_json(str(runs["realtime"][0]))["axes"] == compare_json(str(runs["base"][0]))["axes"]
    )


def test_experiment_manifest_carries_bridge_drops(tmp_path: Path) -> None:
    exp = tmp_path / "tiny.toml"
    exp.write_text(
        'name = "tiny"\nduration_s = 1.0\n[factors.force]\naxis = "x"\nlevels = [5.0, 10.0]\n'
    )
    out = tmp_path / "out"
    res = uwval("simulate", str(exp), "-o", str(out), "--drop", "0.3", "--executor", "inline")
    assert res.returncode == 0, res.stderr
    manifest = json.loads((out / "manifest.json").read_text())
    assert [r["factors"] for r in manifest["runs"]] == [{"force": 5.0}, {"force": 10.0}]
    for r in manifest["runs"]:
        assert r["session"]["drop_prob"] == 0.3
        assert r["bridge"]["dropped"] > 0.15 * r["bridge"]["sent"]
        assert (out / r["log"]).is_file()


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        (("--vehicle", "{tmp}/missing.sdf"), "missing.sdf"),
        (("--vehicle", "{tmp}/missing.toml"), "missing.toml"),
        (("--vehicle", "nautilus"), "nautilus"),
        (("--duration", "-1"), "--duration"),
        (("--duration", "inf"), "--duration"),
        (("--format", "unknown"), "--format"),
        (("--format", "rosbag1"), ".mcap"),  # suffix and format disagree
        (("--unity-map", "ned"), "Unity map"),
        (("--drop", "1.5"), "drop"),
        (("--latency", "nan"), "latency"),
        (("--jitter", "-1"), "jitter"),
        (("--frame-rate", "inf"), "frame rate"),
        (("--unity-clock-offset", "nan"), "clock offset"),
        (("--publish-rate", "0"), "publish rate"),
        (("--torque", "1,2"), "--torque"),
        (("-o", "/proc/uwval-no-such-dir/run.mcap"), "/proc/uwval-no-such-dir"),
        (("--vehicle", "{tmp}/no_inertia.toml"), "'inertia' (a list ixx, iyy, izz"),
        (("--vehicle", "{tmp}/bad_mass.sdf"), "<inertial><mass>: expected 1 numbers"),
        (("{tmp}/missing_exp.toml",), "missing_exp.toml"),
        (("{tmp}/bad.toml",), "bad.toml"),
        (("{tmp}/empty_factor.toml",), "factors.force"),
        (("{tmp}/bad.toml", "-o", "/proc/uwval-no-such-dir"), "bad.toml"),
        (("/proc/uwval-no-such-dir/x.toml",), "x.toml"),
    ],
)
def test_bad_input_is_one_clean_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], args: tuple[str, ...], needle: str
) -> None:
    (tmp_path / "bad.toml").write_text("name = 'x'\n[factors\n")
    (tmp_path / "empty_factor.toml").write_text("[factors]\nforce = []\n")
    (tmp_path / "no_inertia.toml").write_text("mass = 1\n")
    (tmp_path / "bad_mass.sdf").write_text(
        (REPO / "data" / "vehicles" / "tethys_sdf" / "model.sdf")
        .read_text()
        .replace("<mass>147.8671</mass>", "<mass>heavy</mass>")
    )
    argv = [a.replace("{tmp}", str(tmp_path)) for a in args]
    if "-o" not in argv:
        argv += ["-o", str(tmp_path / "run.mcap")]
    if "--duration" not in argv:
        argv = ["--duration", "0.2", *argv]
    # In-process through the console entry point (the same code path as the `uwval` script,
    # without an interpreter start per case): anything but a UwvalError would propagate here.
    with pytest.raises(SystemExit) as stop:
        main(["simulate", *argv])
    err = capsys.readouterr().err
    assert stop.value.code == 2, err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("error:"), err
    assert needle.replace("{tmp}", str(tmp_path)) in lines[0]
    assert not (tmp_path / "run.mcap").exists()
