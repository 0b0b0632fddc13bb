"""Experiment files: the demo's default factorial, the second example, and errors."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest

from uwval.errors import ConfigError
from uwval.simulator import FLUID_ADDED_MASS, load_experiment, simulate, simulate_batch

EXPERIMENTS = Path(__file__).resolve().parents[2] / "data" / "experiments"


def test_default_experiment_is_the_papers_study() -> None:
    """3 x 3 x 3 factorial of force (N), torque (N m), current (m/s), two seeds each, on the
    BlueROV2 Heavy, driven by held teleop keys (the paper's study; issue 18)."""
    exp = load_experiment(EXPERIMENTS / "default.toml")
    runs = exp.runs()
    assert len(runs) == 27 * 2
    assert [f.name for f in exp.factors] == ["force", "torque", "current"]
    for f in exp.factors:
        assert len(f.levels) == 3
    combos = {(r.factors["force"], r.factors["torque"], r.factors["current"]) for r in runs}
    assert len(combos) == 27  # every combination, each repeated with two seeds
    assert {r.repeat for r in runs} == {0, 1}
    names = [r.name for r in runs]
    assert len(set(names)) == 54
    assert all(re.fullmatch(r"[A-Za-z0-9._=+-]+", n) for n in names)
    assert all(r.duration_s <= 4 for r in runs)
    assert len({r.seed for r in runs}) == 54
    json.dumps([r.factors for r in runs])  # JSON scalars
    assert runs[0].vehicle.name == "bluerov2_heavy" and exp.model == FLUID_ADDED_MASS
    assert exp.unity["transport"] == "real-endpoint" and exp.unity["float32"] is True
    # the levels are the held keys' force and torque: surge, heave, sway; yaw, roll, pitch
    r = runs[-1]
    fo, tq, c = r.inputs.evaluate(np.array([0.5, 1.7, 2.0, 2.7, 3.5]))
    lf, lt, lc = r.factors["force"], r.factors["torque"], r.factors["current"]
    np.testing.assert_array_equal(fo[:, 0], [lf, 0, 0, 0, 0])  # i held 0.2-1.2 s
    np.testing.assert_array_equal(fo[:, 2], [0, lf, 0, 0, 0])  # t held 1.0-1.8 s
    np.testing.assert_array_equal(fo[:, 1], [0, lf, lf, 0, 0])  # J held 1.6-2.6 s
    np.testing.assert_array_equal(tq[:, 2], [lt, 0, 0, 0, 0])  # j held 0.4-1.4 s
    np.testing.assert_array_equal(tq[:, 0], [0, lt, lt, 0, 0])  # u held 1.6-2.2 s
    np.testing.assert_array_equal(tq[:, 1], [0, 0, 0, lt, 0])  # y held 2.4-3.0 s
    np.testing.assert_array_equal(c, np.tile([lc, 0, 0], (5, 1)))  # current east


def test_default_experiment_excites_all_six_dof_and_factors_matter() -> None:
    exp = load_experiment(EXPERIMENTS / "default.toml")
    runs = [r for r in exp.runs() if r.repeat == 0]
    kw = {k: v for k, v in runs[0].simulate_kwargs().items() if k != "seed"}
    results = simulate_batch([r.vehicle for r in runs], [r.inputs for r in runs], 4.0, **kw)
    by = {tuple(r.factors.values()): res for r, res in zip(runs, results, strict=True)}
    from uwval.rotations import rpy_from_quat

    for res in results:
        pos = res.vehicle.position
        rpy = np.degrees(rpy_from_quat(res.vehicle.orientation))
        assert np.ptp(pos, axis=0).min() > 0.01  # x, y, z each move > 1 cm
        assert np.ptp(rpy, axis=0).min() > 0.5  # roll, pitch, yaw each > 0.5 deg
    lo = by[(5.0, 0.1, 0.0)].vehicle.position[-1]
    hi = by[(20.0, 0.1, 0.0)].vehicle.position[-1]
    assert hi[0] > 1.5 * lo[0]  # more surge force, farther ahead
    drift = by[(5.0, 0.1, 0.25)].vehicle.position[-1] - lo
    assert drift[0] > 0.3  # the eastward current carries it east
    yaw = {
        t: np.ptp(rpy_from_quat(by[(5.0, t, 0.0)].vehicle.orientation)[:, 2]) for t in (0.1, 0.5)
    }
    assert yaw[0.5] > 2 * yaw[0.1]
    single = simulate(runs[3].vehicle, runs[3].inputs, 4.0, **runs[3].simulate_kwargs())
    np.testing.assert_allclose(single.vehicle.position, results[3].vehicle.position, atol=1e-9)


def test_second_example_exercises_profiles_keys_params_repeats() -> None:
    exp = load_experiment(EXPERIMENTS / "bluerov2_sweep.toml")
    runs = exp.runs()
    assert len(runs) == 2 * 1 * 2 * 2
    assert exp.model.implicit
    assert {r.repeat for r in runs} == {0, 1}
    assert {r.vehicle.hydro["xUabsU"] for r in runs} == {-141.0, -200.0}
    r = runs[0]
    f, tq, c = r.inputs.evaluate([0.5, 1.5, 4.5])
    np.testing.assert_allclose(f[:, 2], [0, 5, 5])  # stepped heave at t0 = 1 s
    np.testing.assert_allclose(f[:, 0], [10, 10, 0])  # key 'i' held 0-2 s
    np.testing.assert_allclose(tq[:, 2], [0, 0.2, 1.0])  # pulse on, then key 'j' (pulse off)
    np.testing.assert_allclose(c[:, 0], [0.0125, 0.0375, 0.1])  # ramp to 0.1 m/s over 4 s
    assert r.simulate_kwargs()["model"].implicit


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
