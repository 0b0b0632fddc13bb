"""model_sensitivity: each variant's shift equals the one measured from direct runs, is zero where
the physics says the variant's terms see zeros, grows with the input that excites it, and a
diverging variant is reported as diverged with no numbers."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from uwval.errors import ConfigError
from uwval.rotations import rpy_from_quat
from uwval.simulator import (
    FLUID_ADDED_MASS,
    PLUGIN_ADDED_MASS,
    AddedMass,
    CaSign,
    CoriolisEntries,
    load_vehicle,
    simulate,
)
from uwval.simulator.sensitivity import (
    SCHEMA,
    ReferenceInput,
    model_sensitivity,
    write_sensitivity,
)

DOC_KEYS = {
    "schema", "vehicle", "vehicle_source", "duration_s", "dt_s", "publish_rate_hz",
    "reference_input", "baseline", "variants",
}  # fmt: skip
VARIANT_KEYS = {
    "name", "label", "model", "diverged", "diverged_at_s", "position_max_m",
    "position_final_m", "yaw_max_deg", "yaw_final_deg", "rotation_max_deg",
}  # fmt: skip


def test_default_report_matches_direct_runs_and_flags_the_diverging_scheme() -> None:
    rep = model_sensitivity(duration_s=2.0)
    assert rep.baseline == FLUID_ADDED_MASS and rep.vehicle == "bluerov2_heavy"
    by = {v.name: v for v in rep.variants}
    assert list(by) == ["coriolis", "added_mass", "ca_sign"]
    assert by["coriolis"].model.coriolis is CoriolisEntries.LEGACY
    assert by["ca_sign"].model.ca_sign is CaSign.GAZEBO
    # the plugin's explicit added mass diverges with Z_wdot 18.68 kg > m 13.5 kg: no numbers
    explicit = by["added_mass"]
    assert explicit.model.added_mass is AddedMass.EXPLICIT
    assert explicit.diverged and 0 < explicit.diverged_at_s < 1.0  # type: ignore[operator]
    assert explicit.position_max_m is None and explicit.yaw_max_deg is None
    # the others: the distances of two direct runs, final and max
    veh = load_vehicle("bluerov2_heavy")
    inputs = ReferenceInput(10.0, 0.25, 0.1).profile()
    base = simulate(veh, inputs, 2.0, model=FLUID_ADDED_MASS)
    for name in ("coriolis", "ca_sign"):
        v = by[name]
        run = simulate(veh, inputs, 2.0, model=v.model)
        d = np.linalg.norm(run.vehicle.position - base.vehicle.position, axis=1)
        assert v.position_max_m == pytest.approx(d.max(), rel=1e-12)
        assert v.position_final_m == pytest.approx(d[-1], rel=1e-12)
        dyaw = np.degrees(
            rpy_from_quat(run.vehicle.orientation)[-1, 2]
            - rpy_from_quat(base.vehicle.orientation)[-1, 2]
        )
        assert v.yaw_final_deg == pytest.approx(abs(dyaw), rel=1e-9)
        assert v.position_max_m > 1e-4 and v.rotation_max_deg > 0.1  # type: ignore[operator]


def test_zero_where_the_variant_terms_see_zeros_and_growing_with_the_run() -> None:
    """Tethys with the plugin's own model (its explicit added mass is stable). Held in a pure
    eastward current it only surges: every added-mass Coriolis entry multiplies two twist
    components, one of them zero, so the Coriolis variants move nothing, while the explicit /
    implicit added-mass choice changes the surge transient. Excited by the keys, every variant
    moves it, and a longer run (whose first seconds are the shorter run) moves it no less."""
    tethys = load_vehicle("tethys")
    drift = model_sensitivity(
        tethys, duration_s=2.0, force_n=0.0, torque_nm=0.0, current_ms=0.3,
        baseline=PLUGIN_ADDED_MASS,
    )  # fmt: skip
    by = {v.name: v for v in drift.variants}
    assert by["coriolis"].position_max_m == 0.0 and by["coriolis"].rotation_max_deg == 0.0
    assert by["ca_sign"].position_max_m == 0.0 and by["ca_sign"].rotation_max_deg == 0.0
    assert 0 < by["added_mass"].position_max_m < 0.01  # type: ignore[operator]
    assert by["added_mass"].rotation_max_deg == 0.0
    short = model_sensitivity(tethys, duration_s=2.0, torque_nm=1.0, baseline=PLUGIN_ADDED_MASS)
    long = model_sensitivity(tethys, duration_s=4.0, torque_nm=1.0, baseline=PLUGIN_ADDED_MASS)
    for a, b in zip(short.variants, long.variants, strict=True):
        assert not a.diverged and not b.diverged
        assert 0 < a.position_max_m <= b.position_max_m  # type: ignore[operator]
        assert 0 < a.rotation_max_deg <= b.rotation_max_deg  # type: ignore[operator]


def test_written_json_follows_the_documented_schema(tmp_path: Path) -> None:
    rep = model_sensitivity(duration_s=0.5)
    path = write_sensitivity(rep, tmp_path / "sensitivity.json")
    doc = json.loads(path.read_text())
    assert set(doc) == DOC_KEYS and doc["schema"] == SCHEMA
    assert doc["baseline"] == {
        "coriolis": "fixed", "added_mass": "implicit", "ca_sign": "fossen",
        "label": "the default experiment's model",
    }  # fmt: skip
    assert [v["name"] for v in doc["variants"]] == ["coriolis", "added_mass", "ca_sign"]
    for v in doc["variants"]:
        assert set(v) == VARIANT_KEYS
        numbers = [v[k] for k in VARIANT_KEYS if k.endswith(("_m", "_deg"))]
        assert all(x is None for x in numbers) if v["diverged"] else all(x >= 0 for x in numbers)
    # the docs page carries this schema for the reports engineer
    docs = Path(__file__).resolve().parents[2] / "docs" / "simulator.md"
    if docs.exists():
        text = docs.read_text()
        assert all(f'"{k}"' in text for k in DOC_KEYS | VARIANT_KEYS)


def test_the_demos_call_labels_the_default_model() -> None:
    """The demo passes the experiment's own vehicle and model: still the default's label."""
    from uwval.resources import data_path
    from uwval.simulator import load_experiment

    exp = load_experiment(data_path("experiments", "default.toml"))
    rep = model_sensitivity(exp.vehicle, duration_s=0.5, baseline=exp.model)
    assert rep.baseline_label == "the default experiment's model"
    assert ".." not in rep.vehicle_source and rep.vehicle_source.endswith("model.sdf")


def test_bad_arguments_are_refused_in_one_line() -> None:
    with pytest.raises(ConfigError, match="duration_s must be > 0"):
        model_sensitivity(duration_s=-1.0)
    with pytest.raises(ConfigError, match="force_n must be a finite number"):
        model_sensitivity(force_n=float("nan"))


def test_a_diverging_baseline_is_an_error() -> None:
    from uwval.simulator.errors import SimulationError

    explicit = replace(FLUID_ADDED_MASS, added_mass=AddedMass.EXPLICIT)
    with pytest.raises(SimulationError, match="baseline model diverged"):
        model_sensitivity(duration_s=1.0, baseline=explicit)
