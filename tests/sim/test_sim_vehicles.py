"""Vehicle presets, TOML vehicle files and the Gazebo model SDF reader."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

from uwval.errors import ConfigError
from uwval.simulator import load_vehicle, load_vehicle_sdf, preset_names
from uwval.simulator.vehicle import Vehicle, classify_hydro_name

DATA = Path(__file__).resolve().parents[2] / "data" / "vehicles"
SDF = DATA / "tethys_sdf" / "model.sdf"


def test_presets() -> None:
    assert {"tethys", "bluerov2_heavy", "bluerov2_heavy_stable"} <= set(preset_names())
    t = load_vehicle()
    assert t.name == "tethys"
    assert t.mass == 147.8671
    np.testing.assert_array_equal(np.diag(t.inertia), [3.0, 41.98, 41.98])
    assert t.hydro["xDotU"] == -4.876161
    assert t.hydro["yDotV"] == t.hydro["zDotW"] == -126.324739
    assert t.hydro["mDotQ"] == t.hydro["nDotR"] == -33.46
    assert t.hydro["xUabsU"] == -6.2282
    assert t.hydro["yVabsV"] == t.hydro["zWabsW"] == -601.27
    assert t.hydro["kPabsP"] == -0.1916
    assert t.hydro["mQabsQ"] == t.hydro["nRabsR"] == -632.698957
    assert t.buoyancy == pytest.approx(t.weight)  # neutrally buoyant
    b = load_vehicle("bluerov2_heavy")
    assert (b.mass, b.displaced_volume) == (13.5, 0.0134)
    np.testing.assert_array_equal(b.center_of_buoyancy, [0, 0, 0.01])
    ma = -np.diag(b.added_mass_matrix())
    np.testing.assert_allclose(ma, [6.36, 7.12, 18.68, 0.189, 0.135, 0.222])
    lin, qabs, _ = b.damping_terms()
    np.testing.assert_allclose(-np.diag(lin), [13.7, 0, 33, 0, 0.8, 0])
    np.testing.assert_allclose(
        -np.array([qabs[i, i, i] for i in range(6)]), [141, 217, 190, 1.19, 0.47, 1.5]
    )
    s = load_vehicle("bluerov2_heavy_stable")
    assert s.explicit_added_mass_unstable_axes() == []
    assert abs(s.hydro["zDotW"]) < s.mass


def test_gz_parameter_names_map_to_gz_indices() -> None:
    assert classify_hydro_name("xDotU") == ("added_mass", (0, 0))
    assert classify_hydro_name("nDotV") == ("added_mass", (5, 1))
    assert classify_hydro_name("yR") == ("linear", (1, 5))
    assert classify_hydro_name("xUabsU") == ("quadratic_abs", (0, 0, 0))
    assert classify_hydro_name("kPabsQ") == ("quadratic_abs", (3, 3, 4))
    assert classify_hydro_name("xUV") == ("quadratic", (0, 0, 1))
    with pytest.raises(ConfigError, match="'xFoo'"):
        classify_hydro_name("xFoo")


def test_sdf_reader_matches_the_preset() -> None:
    sdf = load_vehicle_sdf(SDF)
    preset = load_vehicle("tethys")
    assert sdf.name == "tethys"
    assert sdf.mass == preset.mass
    assert sdf.hydro == preset.hydro
    np.testing.assert_allclose(sdf.inertia, np.diag([3.0, 41.980233, 41.980233]))
    assert sdf.displaced_volume == pytest.approx(2 * 0.3 * 0.246445166667)
    assert sdf.buoyancy == pytest.approx(sdf.weight, rel=1e-9)
    assert load_vehicle(str(SDF)).hydro == sdf.hydro
    assert load_vehicle(str(SDF.parent)).name == "tethys"  # a model folder


def _sdf(tmp_path: Path, text: str) -> Path:
    p = tmp_path / "model.sdf"
    p.write_text(text)
    return p


MODEL = """<?xml version="1.0"?>
<sdf version="1.9"><world name="w"><gravity>0 0 -9.81</gravity>
  <plugin filename="gz-sim-buoyancy-system" name="gz::sim::systems::Buoyancy">
    <uniform_fluid_density>1025</uniform_fluid_density></plugin>
  <model name="rov">
    <link name="base">
      <inertial><pose>0 0 -0.02 0 0 0</pose><mass>10</mass>
        <inertia><ixx>0.2</ixx><iyy>0.3</iyy><izz>0.4</izz><ixy>0.01</ixy></inertia></inertial>
      {collisions}
    </link>
    <plugin filename="gz-sim-hydrodynamics-system" name="gz::sim::systems::Hydrodynamics">
      <link_name>base</link_name><xDotU>-2</xDotU><xUabsU>-20</xUabsU><nRabsV>-1.5</nRabsV>
      <default_current>0.1 0 0</default_current>{extra}
    </plugin>
  </model></world></sdf>
"""


def test_sdf_world_with_buoyancy_shapes_and_gravity(tmp_path: Path) -> None:
    coll = (
        '<collision name="a"><pose>0.1 0 0 0 0 0</pose><geometry><sphere><radius>0.1</radius>'
        "</sphere></geometry></collision>"
        '<collision name="b"><geometry><cylinder><radius>0.05</radius><length>0.4</length>'
        "</cylinder></geometry></collision>"
        '<collision name="m"><geometry><mesh><uri>hull.dae</uri></mesh></geometry></collision>'
    )
    v = load_vehicle_sdf(_sdf(tmp_path, MODEL.format(collisions=coll, extra="")))
    vs = 4 / 3 * np.pi * 0.1**3
    vc = np.pi * 0.05**2 * 0.4
    assert v.displaced_volume == pytest.approx(vs + vc)
    np.testing.assert_allclose(v.center_of_buoyancy, [0.1 * vs / (vs + vc), 0, 0.02])
    assert v.water_density == 1025
    assert v.gravity == pytest.approx(9.81)
    assert v.inertia[0, 1] == 0.01
    assert v.hydro == {"xDotU": -2.0, "xUabsU": -20.0, "nRabsV": -1.5}
    np.testing.assert_array_equal(v.default_current, [0.1, 0, 0])
    assert any("mesh" in n for n in v.notes)
    assert any("inertial pose offset" in n for n in v.notes)


@pytest.mark.parametrize(
    ("old", "new", "match"),
    [
        ("<mass>10</mass>", "", r"missing parameter <inertial><mass>"),
        ("<mass>10</mass>", "<mass>ten</mass>", r"<inertial><mass>: expected 1 numbers"),
        ("<ixx>0.2</ixx>", "", r"<inertia><ixx>"),
        ("<xUabsU>-20</xUabsU>", "<xUabsQQ>-20</xUabsQQ>", r"Hydrodynamics <xUabsQQ>.*unknown"),
        ("<xDotU>-2</xDotU>", "<xDotU>abc</xDotU>", r"Hydrodynamics <xDotU>"),
        ("<link_name>base</link_name>", "<link_name>hull</link_name>", r"'hull' names no link"),
        ("<mass>10</mass>", "<mass>-1</mass>", r"mass must be a positive number"),
    ],
)
def test_sdf_errors_name_the_parameter(tmp_path: Path, old: str, new: str, match: str) -> None:
    text = MODEL.format(collisions="", extra="").replace(old, new)
    with pytest.raises(ConfigError, match=match):
        load_vehicle_sdf(_sdf(tmp_path, text))


def test_sdf_structural_errors(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="invalid XML"):
        load_vehicle_sdf(_sdf(tmp_path, "<sdf><model>"))
    with pytest.raises(ConfigError, match="no <model>"):
        load_vehicle_sdf(_sdf(tmp_path, "<sdf/>"))
    with pytest.raises(ConfigError, match="no Hydrodynamics plugin"):
        load_vehicle_sdf(_sdf(tmp_path, "<sdf><model name='m'><link name='l'/></model></sdf>"))
    with pytest.raises(ConfigError, match="does not exist"):
        load_vehicle_sdf(tmp_path / "nope.sdf")


def test_vehicle_toml_roundtrip_and_errors(tmp_path: Path) -> None:
    good = tmp_path / "v.toml"
    good.write_text(
        'name = "mini"\nmass = 20\ninertia = {ixx = 1, iyy = 2, izz = 3, ixy = 0.1}\n'
        "volume = 0.021\ncenter_of_buoyancy = [0, 0, 0.02]\n"
        "[hydrodynamics]\nxUabsU = -10\nxDotU = -1\n"
    )
    v = load_vehicle(str(good))
    assert v.name == "mini"
    assert v.inertia[1, 0] == 0.1
    assert v.buoyancy - v.weight == pytest.approx(1000 * 0.021 * 9.8 - 20 * 9.8)
    cases = {
        "inertia = [1, 2, 3]\n": "missing parameter 'mass'",
        "mass = 1\n": "missing parameter 'inertia'",
        "mass = 'x'\ninertia = [1, 2, 3]\n": "'mass' must be a number",
        "mass = 1\ninertia = [1, 2]\n": "inertia must have 3",
        "mass = 1\ninertia = [1, 2, 3]\nvolume = 'lots'\n": "volume must be a number",
        "mass = 1\ninertia = [1, 2, 3]\n[hydrodynamics]\nxFoo = 1\n": "hydrodynamic .* .xFoo.",
        "mass = 1\ninertia = [1, 2, 3]\n[hydrodynamics]\nxU = 'a'\n": "xU must be a number",
        "mass = 1\ninertia = [1, 2, 3]\ncolour = 'red'\n": "unknown key 'colour'",
        "mass = 1\ninertia = [1, 2, -3]\n": "positive definite",
        "mass = 1\ninertia = [1, 2, 3\n": "invalid TOML",
    }
    for i, (text, match) in enumerate(cases.items()):
        p = tmp_path / f"bad{i}.toml"
        p.write_text(text)
        with pytest.raises(ConfigError, match=match) as exc:
            load_vehicle(str(p))
        assert str(p) in str(exc.value)
    with pytest.raises(ConfigError, match="unknown vehicle 'submarine'"):
        load_vehicle("submarine")


def test_with_params_and_parameter_lookup() -> None:
    t = load_vehicle()
    v = t.with_params(mass=100.0, xUabsU=-10.0, izz=50.0)
    assert v.mass == 100.0
    assert v.parameter("xUabsU") == -10.0
    assert v.parameter("izz") == 50.0
    assert v.buoyancy == pytest.approx(v.weight)  # neutral follows the mass
    assert t.parameter("xUabsU") == -6.2282  # the original is untouched
    assert t.parameter("yUV") == 0.0
    with pytest.raises(ConfigError, match="unknown hydrodynamic parameter 'speed'"):
        t.with_params(speed=1.0)


def test_preset_copied_elsewhere_loads_by_path(tmp_path: Path) -> None:
    dst = tmp_path / "my_rov.toml"
    shutil.copy(DATA / "bluerov2_heavy.toml", dst)
    assert load_vehicle(dst).hydro == load_vehicle("bluerov2_heavy").hydro


def test_vehicle_validation() -> None:
    with pytest.raises(ConfigError, match="symmetric"):
        Vehicle("x", 1.0, np.array([[1, 0.5, 0], [0, 1, 0], [0, 0, 1]], dtype=float))
    with pytest.raises(ConfigError, match="volume"):
        Vehicle("x", 1.0, np.eye(3), volume=-1.0)
