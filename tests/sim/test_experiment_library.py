"""The experiment pipeline as a library (uwval.bridge.experiment), without the CLI: options in,
typed result out, logs on disk whose Gazebo poses are the simulator's; embedded experiments by
name from any folder; nothing of uwval.cli imported on the way."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from cli_runner import run_uwval

from uwval.batch import Executor
from uwval.bridge.experiment import (
    ExperimentResult,
    SimulateOptions,
    SingleRun,
    WrenchFrame,
    embedded_experiments,
    resolve_experiment,
    run_experiment,
    run_single,
)
from uwval.errors import ConfigError
from uwval.io import read_stream
from uwval.simulator import (
    FLUID_ADDED_MASS,
    CaSign,
    GazeboModel,
    load_experiment,
    simulate,
)

SMALL = """name = "small"
vehicle = "bluerov2_heavy"
added_mass = "implicit"
ca_sign = "fossen"
duration_s = 1.0
[factors.force]
keys = "i@0.1:0.6"
levels = [5.0, 20.0]
"""


def test_run_experiment_writes_logs_of_the_simulators_poses(tmp_path: Path) -> None:
    exp = tmp_path / "small.toml"
    exp.write_text(SMALL)
    out = tmp_path / "out"
    result = run_experiment(SimulateOptions(output=out, experiment=exp, executor=Executor.INLINE))
    assert isinstance(result, ExperimentResult) and result.ok
    assert result.manifest_path == out / "manifest.json"
    assert json.loads(result.manifest_path.read_text()) == result.manifest
    assert result.manifest["experiment"]["model"] == FLUID_ADDED_MASS.to_dict()
    assert [r["factors"]["force"] for r in result.runs] == [5.0, 20.0]
    specs = load_experiment(exp).runs()
    for rec, spec in zip(result.runs, specs, strict=True):
        assert rec["sim"]["model"]["ca_sign"] == "fossen"
        logged = read_stream(out / rec["log"], "/gazebo/model_rov_pose")
        direct = simulate(spec.vehicle, spec.inputs, spec.duration_s, **spec.simulate_kwargs())
        np.testing.assert_array_equal(logged.t, direct.vehicle.t)
        np.testing.assert_allclose(logged.position, direct.vehicle.position, atol=1e-12)
    # the larger held force carries the vehicle farther ahead
    ends = [
        read_stream(out / r["log"], "/gazebo/model_rov_pose").position[-1, 0] for r in result.runs
    ]
    assert ends[1] > 2 * ends[0] > 0


def test_run_single_records_the_model_and_refuses_bad_input(tmp_path: Path) -> None:
    model = GazeboModel(ca_sign=CaSign.FOSSEN)
    run = SingleRun(force=(10.0, 0.0, 0.0), duration_s=1.0, model=model)
    rec = run_single(SimulateOptions(output=tmp_path / "one.mcap", run=run))
    assert Path(rec["log"]).is_file() and rec["sim"]["model"] == model.to_dict()
    assert rec["bridge"]["sent"] > 0
    with pytest.raises(ConfigError, match="--duration must be a positive"):
        run_single(SimulateOptions(output=tmp_path / "x.mcap", run=SingleRun(duration_s=0.0)))
    with pytest.raises(ConfigError, match=r"the suffix \.bag means rosbag1"):
        run_single(SimulateOptions(output=tmp_path / "x.bag", run=run))
    with pytest.raises(ValueError, match="'north'"):
        WrenchFrame("north")


def test_embedded_experiments_by_name_from_any_folder(tmp_path: Path) -> None:
    assert {"default", "quick"} <= set(embedded_experiments())
    assert resolve_experiment("quick").name == "quick.toml"
    with pytest.raises(ConfigError, match=r"experiment file nosuch does not exist \(embedded"):
        resolve_experiment("nosuch")
    with pytest.raises(ConfigError, match="a directory, not an experiment TOML"):
        resolve_experiment(tmp_path)
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    res = run_uwval("simulate", "quick", "-o", "q", "--executor", "inline", cwd=elsewhere)
    assert res.returncode == 0, res.stderr
    manifest = json.loads((elsewhere / "q" / "manifest.json").read_text())
    assert len(manifest["runs"]) == 8 and manifest["experiment"]["name"] == "quick"
    bad = run_uwval("simulate", "nosuch", "-o", "q2", cwd=elsewhere)
    assert bad.returncode == 2 and "embedded experiments: " in bad.stderr
    assert "Traceback" not in bad.stderr


def test_the_library_runs_an_experiment_without_the_cli(tmp_path: Path) -> None:
    exp = tmp_path / "small.toml"
    exp.write_text(SMALL.replace("levels = [5.0, 20.0]", "levels = [5.0]"))
    code = (
        "import sys; from pathlib import Path\n"
        "from uwval.bridge.experiment import SimulateOptions, run_experiment\n"
        "from uwval.batch import Executor\n"
        f"r = run_experiment(SimulateOptions(output=Path({str(tmp_path / 'o')!r}), "
        f"experiment={str(exp)!r}, executor=Executor.INLINE))\n"
        "assert r.ok, r.failed\n"
        "print(sorted(m for m in sys.modules if m.startswith('uwval.cli')))\n"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=120, check=False
    )
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "[]"
