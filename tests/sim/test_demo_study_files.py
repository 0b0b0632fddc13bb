"""The demo's study files: beside the results of a (small) experiment it writes
sensitivity.json for the experiment's own vehicle and model, and analysis.json (the factorial
analysis with partial eta^2 per factor)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from uwval.batch import Executor, compare_batch
from uwval.bridge.experiment import SimulateOptions, run_experiment
from uwval.cli import demo_cmd

SMALL = """name = "tiny"
vehicle = "bluerov2_heavy"
added_mass = "implicit"
ca_sign = "fossen"
duration_s = 1.0
repeats = 2
[factors.force]
keys = "i@0.1:0.6"
levels = [5.0, 20.0]
"""


def test_demo_writes_sensitivity_and_analysis_beside_the_results(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    exp = tmp_path / "tiny.toml"
    exp.write_text(SMALL)
    sim = run_experiment(
        SimulateOptions(output=tmp_path / "out", experiment=exp, executor=Executor.INLINE)
    )
    batch = compare_batch(sim.out_dir, executor=Executor.INLINE, progress=False)
    results = sim.out_dir / "results"
    batch.save(results)
    demo_cmd._write_study_files(batch.table, exp, results)
    doc = json.loads((results / "sensitivity.json").read_text())
    assert doc["schema"] == "uwval-sensitivity/1" and doc["duration_s"] == 1.0
    assert doc["baseline"]["label"] == "the default experiment's model"
    assert [v["name"] for v in doc["variants"]] == ["coriolis", "added_mass", "ca_sign"]
    analysis = json.loads((results / "analysis.json").read_text())
    assert "force" in json.dumps(analysis)
    assert "analysis" in capsys.readouterr().out
