"""Experiment files: the demo's default factorial, the second example, and errors."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest

from uwval.errors import ConfigError
from uwval.simulator import load_experiment, simulate, simulate_batch

EXPERIMENTS = Path(__file__).resolve().parents[1] / "data" / "experiments"


def test_default_experiment_is_the_demo_factorial() -> None:
    exp = load_experiment(EXPERIMENTS / "default.toml")
    runs = exp.runs()
    assert len(runs) == 8
    assert {f.name for f in exp.factors} == {"force", "torque", "current"}
    levels = {(r.factors["force"], r.factors["torque"], r.factors["current"]) for r in runs}
    assert len(levels) == 8  # every combination once
    for f in exp.factors:
        assert len(f.levels) == 2
    names = [r.name for r in runs]
    assert len(set(names)) == 8
    assert all(re.fullmatch(r"[A-Za-z0-9._=+-]+", n) for n in names)
    assert all(r.duration_s <= 10 for r in runs)
    assert len({r.seed for r in runs}) == 8
    json.dumps([r.factors for r in runs])  # JSON scalars
    # the factor levels reach the inputs: force on body x, torque on body z, current on world y
    r = runs[-1]
    fo, tq, c = r.inputs.evaluate(np.array([0.0]))
    assert fo[0].tolist() == [r.factors["force"], 0, 0]
    assert tq[0].tolist() == [0, 0, r.factors["torque"]]
    assert c[0].tolist() == [0, r.factors["current"], 0]
    assert r.vehicle.name == "tethys"


def test_default_experiment_runs_and_factors_matter() -> None:
    runs = load_experiment(EXPERIMENTS / "default.toml").runs()
    results = simulate_batch([r.vehicle for r in runs], [r.inputs for r in runs], 5.0)
    by = {tuple(r.factors.values()): res for r, res in zip(runs, results, strict=True)}
    lo_f = by[(5.0, 0.5, 0.0)].vehicle.position[-1]
    hi_f = by[(20.0, 0.5, 0.0)].vehicle.position[-1]
    assert np.linalg.norm(hi_f) > 1.5 * np.linalg.norm(lo_f)
    drift = by[(5.0, 0.5, 0.3)].vehicle.position[-1] - lo_f
    assert drift[1] > 0.3  # the northward current carries it north
    single = simulate(runs[3].vehicle, runs[3].inputs, 5.0, **runs[3].simulate_kwargs())
    np.testing.assert_allclose(single.vehicle.position, results[3].vehicle.position, atol=1e-12)


def test_second_example_exercises_profiles_keys_params_repeats() -> None:
    exp = load_experiment(EXPERIMENTS / "bluerov2_sweep.toml")
    runs = exp.runs()
    assert len(runs) == 2 * 1 * 2 * 2
    assert exp.implicit_added_mass
    assert {r.repeat for r in runs} == {0, 1}
    assert {r.vehicle.hydro["xUabsU"] for r in runs} == {-141.0, -200.0}
    r = runs[0]
    f, tq, c = r.inputs.evaluate([0.5, 1.5, 4.5])
    np.testing.assert_allclose(f[:, 2], [0, 5, 5])  # stepped heave at t0 = 1 s
    np.testing.assert_allclose(f[:, 0], [10, 10, 0])  # key 'i' held 0-2 s
    np.testing.assert_allclose(tq[:, 2], [0, 0.2, 1.0])  # pulse on, then key 'j' (pulse off)
    np.testing.assert_allclose(c[:, 0], [0.0125, 0.0375, 0.1])  # ramp to 0.1 m/s over 4 s
    assert r.simulate_kwargs()["implicit_added_mass"] is True


def _exp(tmp_path: Path, text: str) -> Path:
    p = tmp_path / "exp.toml"
    p.write_text(text)
    return p


def test_vehicle_parameter_and_vehicle_factors(tmp_path: Path) -> None:
    (tmp_path / "v.toml").write_text(
        "mass = 50\ninertia = [1, 2, 3]\n[hydrodynamics]\nxUabsU = -5\n"
    )
    p = _exp(
        tmp_path,
        'vehicle = "v.toml"\nduration_s = 1\n'
        "[factors.mass]\nlevels = [40, 60]\n"
        '[factors.vehicle]\nlevels = ["tethys", "v.toml"]\n',
    )
    runs = load_experiment(p).runs()
    assert len(runs) == 4
    masses = sorted((r.factors["vehicle"], r.vehicle.mass) for r in runs)
    assert masses == [("tethys", 40.0), ("tethys", 60.0), ("v.toml", 40.0), ("v.toml", 60.0)]


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("[factors.force]\nlevels = []\n", r"factors\.force.*'levels' must be a non-empty list"),
        ("[factors.force]\nlevels = ['a']\n", r"factors\.force.*levels must be numbers"),
        ("[factors.force]\nlevels = [1, 1]\n", r"factors\.force.*duplicate levels"),
        ("[factors.force]\naxis = 'w'\nlevels = [1]\n", r"factors\.force.*axis must be x, y or z"),
        (
            "[factors.force]\nlevels = [1]\nprofile = {kind = 'saw'}\n",
            r"factors\.force.*unknown profile kind 'saw'",
        ),
        ("[factors.speed]\nlevels = [1]\n", r"factors\.speed.*unknown factor kind 'speed'"),
        ("[factors.mass]\nlevels = [1]\naxis = 'x'\n", r"unknown key\(s\) \['axis'\]"),
        ("duration_s = -1\n", "'duration_s' must be > 0"),
        ("repeats = 0\n", "'repeats' must be an integer >= 1"),
        ("vehicle = 'nautilus'\n", "unknown vehicle 'nautilus'"),
        ("colour = 1\n", r"unknown key\(s\) \['colour'\]"),
        ("[baseline]\nkeys = 'z@0:1'\n", "unknown teleop key 'z'"),
        ("[baseline]\nwind = [1, 0, 0]\n", "unknown baseline key 'wind'"),
        ("wrench_frame = 'ned'\n", "wrench_frame"),
        ("duration_s = [\n", "invalid TOML"),
    ],
)
def test_experiment_errors_name_the_problem(tmp_path: Path, text: str, match: str) -> None:
    p = _exp(tmp_path, text)
    with pytest.raises(ConfigError, match=match) as exc:
        load_experiment(p).runs()
    assert str(p) in str(exc.value)


def test_missing_experiment_file(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="does not exist"):
        load_experiment(tmp_path / "none.toml")


def test_no_factors_is_one_run(tmp_path: Path) -> None:
    runs = load_experiment(_exp(tmp_path, "name = 'solo'\nrepeats = 3\n")).runs()
    assert [r.name for r in runs] == ["solo-00-r0", "solo-01-r1", "solo-02-r2"]
    assert [r.seed for r in runs] == [0, 1, 2]
