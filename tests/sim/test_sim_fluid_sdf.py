"""SDFormat's <fluid_added_mass> (gz-sim 8 / DART): read into gz-sim's added-mass names, the
default experiment's SDF equals the bluerov2_heavy preset and runs as it does under
FLUID_ADDED_MASS; added mass given twice, or a bad element, is refused naming the file."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from uwval.errors import ConfigError
from uwval.resources import data_path
from uwval.simulator import FLUID_ADDED_MASS, constant_inputs, load_vehicle, simulate

SDF = data_path("vehicles", "bluerov2_heavy_sdf", "model.sdf")


def test_the_default_vehicles_sdf_is_the_preset() -> None:
    sdf, preset = load_vehicle(SDF), load_vehicle("bluerov2_heavy")
    nonzero = {k: v for k, v in preset.hydro.items() if v != 0.0}
    assert {k: v for k, v in sdf.hydro.items() if v != 0.0} == nonzero
    assert sdf.hydro["zDotW"] == -18.68 and sdf.mass == preset.mass
    np.testing.assert_allclose(sdf.inertia, preset.inertia)
    assert sdf.displaced_volume == pytest.approx(preset.displaced_volume, rel=1e-12)
    np.testing.assert_allclose(sdf.center_of_buoyancy, preset.center_of_buoyancy)
    assert any("FLUID_ADDED_MASS" in n for n in sdf.notes)
    inputs = constant_inputs(force=(10, 0, 5), torque=(0, 0, 0.3), current=(0.1, 0, 0))
    a = simulate(sdf, inputs, 3.0, model=FLUID_ADDED_MASS)
    b = simulate(preset, inputs, 3.0, model=FLUID_ADDED_MASS)
    np.testing.assert_allclose(a.vehicle.position, b.vehicle.position, atol=1e-9)


def test_off_diagonal_terms_are_symmetric(tmp_path: Path) -> None:
    text = SDF.read_text().replace("<xx>6.36</xx>", "<xx>6.36</xx><xq>0.5</xq>")
    (tmp_path / "model.sdf").write_text(text)
    v = load_vehicle(tmp_path / "model.sdf")
    ma = v.added_mass_matrix()
    assert ma[0, 4] == ma[4, 0] == -0.5
    np.testing.assert_array_equal(ma, ma.T)


def test_added_mass_twice_or_a_bad_element_is_refused(tmp_path: Path) -> None:
    twice = SDF.read_text().replace("<xU>-13.7</xU>", "<xU>-13.7</xU><xDotU>-6.36</xDotU>")
    (tmp_path / "a.sdf").write_text(twice)
    with pytest.raises(ConfigError, match=r"a\.sdf.*added mass given twice"):
        load_vehicle(tmp_path / "a.sdf")
    bad = SDF.read_text().replace("<pp>0.189</pp>", "<pw>0.189</pw>")
    (tmp_path / "b.sdf").write_text(bad)
    with pytest.raises(ConfigError, match=r"b\.sdf.*<fluid_added_mass><pw>: expected xx"):
        load_vehicle(tmp_path / "b.sdf")
