"""Finding a vehicle by name: the presets shipped in ``data/vehicles``, a vehicle TOML file or
a Gazebo model SDF. The one module that knows both readers (:mod:`uwval.simulator.vehicle` for
TOML, :mod:`uwval.simulator.sdf` for SDF), so that neither imports the other."""

from __future__ import annotations

from pathlib import Path

from uwval.errors import ConfigError
from uwval.resources import data_path
from uwval.simulator.sdf import load_vehicle_sdf
from uwval.simulator.vehicle import Vehicle, load_vehicle_toml


# ---------------------------------------------------------------------- presets / dispatch
def vehicles_dir() -> Path:
    """The folder of vehicle presets (``data/vehicles``, package data ``uwval.data``)."""
    return data_path("vehicles")


def preset_names() -> list[str]:
    """Names of the vehicle presets shipped in ``data/vehicles``."""
    return sorted(p.stem for p in vehicles_dir().glob("*.toml"))


def load_vehicle(name_or_path: str | Path = "tethys") -> Vehicle:
    """A vehicle from a preset name (``tethys``, ``bluerov2_heavy``, ``bluerov2_heavy_stable``),
    a Gazebo model SDF (``model.sdf`` / ``*.sdf`` or a model folder holding ``model.sdf``),
    or a vehicle TOML file."""
    s = str(name_or_path)
    p = Path(s)
    if p.is_dir() and (p / "model.sdf").exists():
        p = p / "model.sdf"
    if p.suffix.lower() in (".sdf", ".world", ".xml"):
        return load_vehicle_sdf(p)
    if p.suffix.lower() == ".toml":
        return load_vehicle_toml(p)
    preset = vehicles_dir() / f"{s}.toml"
    if preset.exists():
        return load_vehicle_toml(preset)
    raise ConfigError(
        f"unknown vehicle {s!r}: not a preset ({', '.join(preset_names())}), "
        "nor an existing .sdf or .toml file"
    )
