"""Read a Gazebo model (or world) SDF into a :class:`~uwval.simulator.vehicle.Vehicle`.

What is read, as gz-sim uses it:

* the link named by the Hydrodynamics plugin's ``<link_name>`` (or the model's only link):
  ``<inertial>`` mass, inertia (``ixx`` ... ``iyz``) and pose;
* the Hydrodynamics plugin (``gz::sim::systems::Hydrodynamics``, also the ``ignition::gazebo``
  name): every parameter with a gz-sim name (``xDotU``, ``xU``, ``xUabsU``, ``xUU``...),
  ``default_current`` and the flags ``disable_coriolis`` / ``disable_added_mass`` (kept as notes);
* Buoyancy: gz-sim computes the displaced volume from the link's collision shapes; boxes,
  spheres and cylinders are measured here (meshes cannot be, and are reported); the fluid
  density from a Buoyancy plugin's ``<uniform_fluid_density>`` in the same file (default 1000),
  gravity from a world ``<gravity>`` (default 9.8).

The vehicle body origin is the CoG: the centre of buoyancy is stored relative to the inertial
pose. Errors name the file, the element and the missing or bad parameter.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Literal

import numpy as np

from uwval.errors import ConfigError
from uwval.simulator.vehicle import (
    DEFAULT_GRAVITY,
    DEFAULT_WATER_DENSITY,
    Vehicle,
    classify_hydro_name,
)

_HYDRO_PLUGINS = ("hydrodynamics",)
_BUOYANCY_PLUGINS = ("buoyancy",)
_NON_COEFFICIENT_TAGS = {
    "link_name",
    "namespace",
    "water_density",
    "waterDensity",
    "default_current",
    "disable_coriolis",
    "disable_added_mass",
    "lookup_current_x",
    "lookup_current_y",
    "lookup_current_z",
}


def _plugin_kind(el: ET.Element) -> Literal["hydro", "buoyancy", ""]:
    name = (el.get("name", "") + " " + el.get("filename", "")).lower()
    if any(k in name for k in _HYDRO_PLUGINS):
        return "hydro"
    if any(k in name for k in _BUOYANCY_PLUGINS):
        return "buoyancy"
    return ""


def _floats(text: str | None, n: int, where: str) -> list[float]:
    parts = (text or "").split()
    try:
        vals = [float(x) for x in parts]
    except ValueError:
        raise ConfigError(f"{where}: expected {n} numbers, got {text!r}") from None
    if len(vals) != n:
        raise ConfigError(f"{where}: expected {n} numbers, got {text!r}")
    return vals


def _float(el: ET.Element | None, where: str) -> float:
    if el is None:
        raise ConfigError(f"{where}: missing")
    return _floats(el.text, 1, where)[0]


def _pose_xyz(parent: ET.Element, where: str) -> np.ndarray:
    pose = parent.find("pose")
    if pose is None or not (pose.text or "").strip():
        return np.zeros(3)
    vals = _floats(pose.text, 6, f"{where} <pose>")
    return np.array(vals[:3])


def _shape_volume(geom: ET.Element, where: str) -> float | None:
    box = geom.find("box")
    if box is not None:
        sx, sy, sz = _floats(box.findtext("size"), 3, f"{where} <box><size>")
        return sx * sy * sz
    sph = geom.find("sphere")
    if sph is not None:
        r = _float(sph.find("radius"), f"{where} <sphere><radius>")
        return 4.0 / 3.0 * math.pi * r**3
    cyl = geom.find("cylinder")
    if cyl is not None:
        r = _float(cyl.find("radius"), f"{where} <cylinder><radius>")
        length = _float(cyl.find("length"), f"{where} <cylinder><length>")
        return math.pi * r * r * length
    return None


#: SDFormat <fluid_added_mass> element name -> (row, column) of the 6x6 added mass
#: (x y z linear, p q r angular; symmetric: ``xy`` sets both (0, 1) and (1, 0)).
_FLUID_AXES = "xyzpqr"


def _read_fluid_added_mass(
    inertial: ET.Element, hydro: dict[str, float], notes: list[str], where: str
) -> None:
    """Add SDFormat 1.10+'s ``<inertial><fluid_added_mass>`` to ``hydro`` as gz-sim parameter
    names (``xx`` -> ``xDotU``, ``xq`` -> ``xDotQ`` and ``mDotU``...; magnitudes in SDF, SNAME
    sign here) and say in ``notes`` that DART applies it in the mass matrix, i.e. that the
    vehicle is simulated as gz-sim runs it with ``FLUID_ADDED_MASS``."""
    fam = inertial.find("fluid_added_mass")
    if fam is None:
        return
    if any("Dot" in k for k in hydro):
        raise ConfigError(
            f"{where}: added mass given twice, as <fluid_added_mass> and as Hydrodynamics "
            "xDotU... parameters (gz-sim would apply both); keep one"
        )
    forces, velocities = "xyzkmn", "UVWPQR"
    for child in fam:
        tag = child.tag
        if len(tag) != 2 or any(c not in _FLUID_AXES for c in tag):
            raise ConfigError(f"{where} <fluid_added_mass><{tag}>: expected xx, xy, ... rr")
        i, j = _FLUID_AXES.index(tag[0]), _FLUID_AXES.index(tag[1])
        val = -_floats(child.text, 1, f"{where} <fluid_added_mass><{tag}>")[0]
        if val != 0.0:
            hydro[f"{forces[i]}Dot{velocities[j]}"] = val
            hydro[f"{forces[j]}Dot{velocities[i]}"] = val
    notes.append(
        "<fluid_added_mass>: gz-physics' DART applies it in the mass matrix; simulate with "
        "model=FLUID_ADDED_MASS (--added-mass implicit --ca-sign fossen)"
    )


def load_vehicle_sdf(path: str | Path) -> Vehicle:
    """Read a Gazebo ``model.sdf`` (or a world SDF holding one model) into a vehicle."""
    p = Path(path)
    try:
        root = ET.parse(p).getroot()
    except FileNotFoundError:
        raise ConfigError(f"SDF file {p} does not exist") from None
    except ET.ParseError as exc:
        raise ConfigError(f"{p}: invalid XML: {exc}") from None
    models = root.findall(".//model")
    if not models:
        raise ConfigError(f"{p}: no <model> element")
    # the model that carries a Hydrodynamics plugin, else the first one
    model = next(
        (m for m in models if any(_plugin_kind(pl) == "hydro" for pl in m.findall("plugin"))),
        models[0],
    )
    mname = model.get("name", p.parent.name or p.stem)
    where = f"{p}: model {mname!r}"
    hydro_el = next((pl for pl in model.findall("plugin") if _plugin_kind(pl) == "hydro"), None)
    if hydro_el is None:
        raise ConfigError(
            f"{where}: no Hydrodynamics plugin (gz::sim::systems::Hydrodynamics) in the model"
        )
    links = model.findall("link")
    if not links:
        raise ConfigError(f"{where}: no <link>")
    link_name = (hydro_el.findtext("link_name") or "").strip()
    if link_name:
        link = next((lk for lk in links if lk.get("name") == link_name), None)
        if link is None:
            raise ConfigError(
                f"{where}: Hydrodynamics <link_name> {link_name!r} names no link "
                f"(links: {', '.join(lk.get('name', '?') for lk in links)})"
            )
    elif len(links) == 1:
        link = links[0]
    else:
        raise ConfigError(
            f"{where}: Hydrodynamics plugin lacks <link_name> and the model has several links"
        )
    lwhere = f"{where} link {link.get('name')!r}"
    inertial = link.find("inertial")
    if inertial is None:
        raise ConfigError(f"{lwhere}: missing <inertial>")
    mass_el = inertial.find("mass")
    if mass_el is None:
        raise ConfigError(f"{lwhere}: missing parameter <inertial><mass>")
    mass = _float(mass_el, f"{lwhere} <inertial><mass>")
    inertia_el = inertial.find("inertia")
    if inertia_el is None:
        raise ConfigError(f"{lwhere}: missing parameter <inertial><inertia>")
    ivals = {}
    for key in ("ixx", "iyy", "izz"):
        el = inertia_el.find(key)
        if el is None:
            raise ConfigError(f"{lwhere}: missing parameter <inertial><inertia><{key}>")
        ivals[key] = _float(el, f"{lwhere} <inertia><{key}>")
    for key in ("ixy", "ixz", "iyz"):
        el = inertia_el.find(key)
        ivals[key] = 0.0 if el is None else _float(el, f"{lwhere} <inertia><{key}>")
    inertia = np.array(
        [
            [ivals["ixx"], ivals["ixy"], ivals["ixz"]],
            [ivals["ixy"], ivals["iyy"], ivals["iyz"]],
            [ivals["ixz"], ivals["iyz"], ivals["izz"]],
        ]
    )
    cog = _pose_xyz(inertial, f"{lwhere} <inertial>")
    notes: list[str] = []
    if np.any(cog != 0):
        notes.append(
            f"inertial pose offset {cog.tolist()} m: hydrodynamic wrench applied at the CoG "
            "(gz applies it at the link origin)"
        )

    hydro: dict[str, float] = {}
    default_current = np.zeros(3)
    for child in hydro_el:
        tag = child.tag
        if tag in _NON_COEFFICIENT_TAGS:
            if tag == "default_current":
                default_current = np.array(
                    _floats(child.text, 3, f"{where} Hydrodynamics <default_current>")
                )
            elif tag in ("disable_coriolis", "disable_added_mass") and (
                (child.text or "").strip().lower() in ("1", "true")
            ):
                notes.append(f"<{tag}> is set in the SDF but not supported: ignored")
            continue
        try:
            classify_hydro_name(tag)
        except ConfigError as exc:
            raise ConfigError(f"{where} Hydrodynamics <{tag}>: {exc}") from None
        hydro[tag] = _floats(child.text, 1, f"{where} Hydrodynamics <{tag}>")[0]

    _read_fluid_added_mass(inertial, hydro, notes, lwhere)

    volume = 0.0
    moment = np.zeros(3)
    for coll in link.findall("collision"):
        cwhere = f"{lwhere} collision {coll.get('name', '?')!r}"
        geom = coll.find("geometry")
        if geom is None:
            raise ConfigError(f"{cwhere}: missing <geometry>")
        vol = _shape_volume(geom, cwhere)
        if vol is None:
            kinds = ",".join(c.tag for c in geom)
            notes.append(
                f"{cwhere}: {kinds} geometry has no computable volume; ignored for buoyancy"
            )
            continue
        volume += vol
        moment += vol * _pose_xyz(coll, cwhere)
    if volume > 0:
        cob = moment / volume - cog
        vehicle_volume: float | None = volume
    else:
        cob = np.zeros(3)
        vehicle_volume = None
        notes.append("no box/sphere/cylinder collision: taken as neutrally buoyant")

    rho = DEFAULT_WATER_DENSITY
    for pl in root.iter("plugin"):
        if _plugin_kind(pl) == "buoyancy":
            el = pl.find("uniform_fluid_density")
            if el is not None:
                rho = _float(el, f"{p}: Buoyancy <uniform_fluid_density>")
    g = DEFAULT_GRAVITY
    grav = root.find(".//world/gravity")
    if grav is not None:
        gvec = _floats(grav.text, 3, f"{p}: <world><gravity>")
        g = float(np.linalg.norm(gvec))
    return Vehicle(
        name=mname,
        mass=mass,
        inertia=inertia,
        volume=vehicle_volume,
        center_of_buoyancy=cob,
        hydro=hydro,
        water_density=rho,
        gravity=g,
        default_current=default_current,
        source=str(p),
        notes=tuple(notes),
    )
