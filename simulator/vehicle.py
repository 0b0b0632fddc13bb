"""Vehicle parameters in gz-sim's terms: rigid body, Hydrodynamics plugin coefficients, buoyancy.

Frames and units: the body frame is FLU (x forward, y left, z up) with its origin at the centre
of gravity (CoG); the world is ENU. Masses in kg, inertia in kg m^2 about the CoG in body axes,
volume in m^3, lengths in m. Hydrodynamic coefficients keep gz-sim's Hydrodynamics plugin names
and its SNAME sign (added mass and damping derivatives are negative for a normal hull):

* added mass ``<f>Dot<V>`` e.g. ``xDotU``, ``yDotV``, ``nDotR`` (any of the 36 entries),
* linear damping ``<f><V>`` e.g. ``xU``, ``nR``,
* quadratic damping ``<f><V>abs<W>`` e.g. ``xUabsU`` (uses |W|) and ``<f><V><W>`` e.g. ``xUU``,

where ``<f>`` is one of ``x y z k m n`` (force/moment axis) and ``<V>``, ``<W>`` one of
``U V W P Q R`` (body velocity). gz-sim assembles them exactly so (``i*6 + j``, ``i*36 + j*6 + k``).

Vehicles come from presets (``data/vehicles/<name>.toml``), TOML files, or Gazebo model SDF
(:mod:`uwval.simulator.sdf`); :func:`load_vehicle` picks the reader.
"""

from __future__ import annotations

import math
import re
import sys
from dataclasses import dataclass, field, replace
from enum import Enum
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from uwval.errors import ConfigError

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python 3.10 (tomli is a dependency there)
    import tomli as tomllib

F64 = NDArray[np.float64]

#: gz-sim's SNAME letters: force/moment axes and body velocity components.
FORCE_AXES = "xyzkmn"
VELOCITY_AXES = "UVWPQR"

_ADDED_MASS_RE = re.compile(r"^([xyzkmn])Dot([UVWPQR])$")
_LINEAR_RE = re.compile(r"^([xyzkmn])([UVWPQR])$")
_QUAD_ABS_RE = re.compile(r"^([xyzkmn])([UVWPQR])abs([UVWPQR])$")
_QUAD_RE = re.compile(r"^([xyzkmn])([UVWPQR])([UVWPQR])$")

#: Scalar (non-hydrodynamic) parameters a factor or a TOML file may set.
SCALAR_PARAMETERS = ("mass", "volume", "water_density", "gravity")

DEFAULT_WATER_DENSITY = 1000.0  # kg/m^3, as DESIGN.md section 5 (gz Buoyancy's usual value)
DEFAULT_GRAVITY = 9.8  # m/s^2, gz-sim's default world gravity magnitude


class HydroKind(str, Enum):
    """The kinds of gz-sim Hydrodynamics parameters (by the shape of their names)."""

    ADDED_MASS = "added_mass"  # xDotU: added mass
    LINEAR = "linear"  # xU: linear damping
    QUADRATIC_ABS = "quadratic_abs"  # xUabsU: quadratic damping with |.|
    QUADRATIC = "quadratic"  # xUU: quadratic damping

    def __str__(self) -> str:
        return self.value


def classify_hydro_name(name: str) -> tuple[HydroKind, tuple[int, ...]]:
    """Kind (``added_mass``, ``linear``, ``quadratic_abs``, ``quadratic``) and indices of a
    gz-sim Hydrodynamics parameter name; raises :class:`ConfigError` for an unknown name."""
    for kind, rx in (
        (HydroKind.ADDED_MASS, _ADDED_MASS_RE),
        (HydroKind.QUADRATIC_ABS, _QUAD_ABS_RE),
        (HydroKind.LINEAR, _LINEAR_RE),
        (HydroKind.QUADRATIC, _QUAD_RE),
    ):
        mt = rx.match(name)
        if mt:
            idx = (
                FORCE_AXES.index(mt.group(1)),
                *(VELOCITY_AXES.index(g) for g in mt.groups()[1:]),
            )
            return kind, idx
    raise ConfigError(
        f"unknown hydrodynamic parameter {name!r}: expected gz-sim names such as xDotU, xU, "
        "xUabsU or xUU (axis x y z k m n, velocity U V W P Q R)"
    )


@dataclass(frozen=True)
class Vehicle:
    """One rigid underwater vehicle as gz-sim's Hydrodynamics + Buoyancy systems see it.

    Attributes:
        name: preset or model name.
        mass: kg.
        inertia: (3, 3) kg m^2 about the CoG, body FLU axes (symmetric, positive definite).
        volume: displaced volume, m^3 (buoyancy ``rho V g``); ``None`` = neutrally buoyant
            (volume follows ``mass / water_density``, so a mass factor keeps it neutral).
        center_of_buoyancy: (3,) m, body FLU, relative to the CoG.
        hydro: gz-sim Hydrodynamics parameters by name (SNAME sign), see module doc.
        water_density: kg/m^3 for buoyancy.
        gravity: m/s^2 (magnitude; world gravity is -z ENU).
        default_current: (3,) m/s world ENU current of the model (SDF ``default_current``),
            added to the input current.
        source: file the vehicle came from, if any.
        notes: remarks made while reading it (approximations, ignored elements).
    """

    name: str
    mass: float
    inertia: F64
    volume: float | None = None
    center_of_buoyancy: F64 = field(default_factory=lambda: np.zeros(3))
    hydro: dict[str, float] = field(default_factory=dict)
    water_density: float = DEFAULT_WATER_DENSITY
    gravity: float = DEFAULT_GRAVITY
    default_current: F64 = field(default_factory=lambda: np.zeros(3))
    source: str = ""
    notes: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        where = f"vehicle {self.name!r}" + (f" ({self.source})" if self.source else "")
        object.__setattr__(self, "inertia", np.array(self.inertia, dtype=np.float64))
        object.__setattr__(
            self, "center_of_buoyancy", np.array(self.center_of_buoyancy, dtype=np.float64)
        )
        object.__setattr__(
            self, "default_current", np.array(self.default_current, dtype=np.float64)
        )
        if not (math.isfinite(self.mass) and self.mass > 0):
            raise ConfigError(f"{where}: mass must be a positive number of kg, got {self.mass}")
        if self.inertia.shape != (3, 3) or not np.all(np.isfinite(self.inertia)):
            raise ConfigError(f"{where}: inertia must be a finite 3x3 matrix")
        if not np.allclose(self.inertia, self.inertia.T):
            raise ConfigError(f"{where}: inertia must be symmetric (ixy, ixz, iyz)")
        if np.linalg.eigvalsh(self.inertia).min() <= 0:
            raise ConfigError(f"{where}: inertia must be positive definite (ixx, iyy, izz > 0)")
        if self.volume is not None and not (math.isfinite(self.volume) and self.volume >= 0):
            raise ConfigError(f"{where}: volume must be >= 0 m^3, got {self.volume}")
        if self.center_of_buoyancy.shape != (3,):
            raise ConfigError(f"{where}: center_of_buoyancy must be 3 numbers (m, body FLU)")
        if self.default_current.shape != (3,):
            raise ConfigError(f"{where}: default_current must be 3 numbers (m/s, world ENU)")
        for key in ("water_density", "gravity"):
            val = getattr(self, key)
            if not (math.isfinite(val) and val >= 0):
                raise ConfigError(f"{where}: {key} must be a non-negative number, got {val}")
        clean: dict[str, float] = {}
        for k, val in self.hydro.items():
            classify_hydro_name(k)
            try:
                fv = float(val)
            except (TypeError, ValueError):
                raise ConfigError(f"{where}: parameter {k} must be a number, got {val!r}") from None
            if not math.isfinite(fv):
                raise ConfigError(f"{where}: parameter {k} must be finite, got {val!r}")
            clean[k] = fv
        object.__setattr__(self, "hydro", clean)

    # ------------------------------------------------------------------ derived quantities
    @property
    def displaced_volume(self) -> float:
        """Displaced volume in m^3 (``mass / water_density`` when neutrally buoyant)."""
        if self.volume is None:
            return self.mass / self.water_density if self.water_density > 0 else 0.0
        return self.volume

    @property
    def buoyancy(self) -> float:
        """Buoyancy force magnitude ``rho V g`` in N (world +z)."""
        return self.water_density * self.displaced_volume * self.gravity

    @property
    def weight(self) -> float:
        """Weight ``m g`` in N (world -z)."""
        return self.mass * self.gravity

    def added_mass_matrix(self) -> F64:
        """6x6 added mass ``Ma``, SNAME sign (``Ma[0, 0] = xDotU``), as gz-sim builds it."""
        ma = np.zeros((6, 6))
        for k, val in self.hydro.items():
            kind, idx = classify_hydro_name(k)
            if kind is HydroKind.ADDED_MASS:
                ma[idx] = val
        return ma

    def damping_terms(self) -> tuple[F64, F64, F64]:
        """gz-sim's damping arrays: linear (6, 6), quadratic-abs (6, 6, 6), quadratic (6, 6, 6)."""
        lin = np.zeros((6, 6))
        qabs = np.zeros((6, 6, 6))
        quad = np.zeros((6, 6, 6))
        for k, val in self.hydro.items():
            kind, idx = classify_hydro_name(k)
            if kind is HydroKind.LINEAR:
                lin[idx] = val
            elif kind is HydroKind.QUADRATIC_ABS:
                qabs[idx] = val
            elif kind is HydroKind.QUADRATIC:
                quad[idx] = val
        return lin, qabs, quad

    def rigid_body_mass_matrix(self) -> F64:
        """6x6 M_RB about the CoG: diag(m, m, m) and the inertia tensor."""
        m = np.zeros((6, 6))
        m[:3, :3] = np.eye(3) * self.mass
        m[3:, 3:] = self.inertia
        return m

    def explicit_added_mass_unstable_axes(self) -> list[str]:
        """Axes where Gazebo's explicit (lagged) added mass diverges: |Ma_ii| >= M_RB_ii.

        The lagged force ``Ma (nu_r[k] - nu_r[k-1]) / dt`` feeds back the last step's
        acceleration with gain -|Ma_ii| / M_RB_ii per step; at or beyond 1 it grows.
        """
        ma = self.added_mass_matrix()
        mrb = self.rigid_body_mass_matrix()
        out = []
        for i in range(6):
            if abs(ma[i, i]) >= mrb[i, i]:
                out.append(
                    f"{FORCE_AXES[i]}Dot{VELOCITY_AXES[i]} = {ma[i, i]:g} "
                    f"(|.| >= {mrb[i, i]:g} {'kg' if i < 3 else 'kg m^2'})"
                )
        return out

    # ------------------------------------------------------------------ variation
    def parameter(self, name: str) -> float:
        """Value of a scalar parameter (``mass``, ``volume``, ..., ``ixx``..., or a gz name)."""
        if name in ("ixx", "iyy", "izz", "ixy", "ixz", "iyz"):
            i, j = _INERTIA_INDEX[name]
            return float(self.inertia[i, j])
        if name == "volume":
            return self.displaced_volume
        if name in SCALAR_PARAMETERS:
            return float(getattr(self, name))
        classify_hydro_name(name)
        return self.hydro.get(name, 0.0)

    def with_params(self, **params: float) -> Vehicle:
        """A copy with parameters changed: ``mass``, ``volume``, ``water_density``,
        ``gravity``, inertia entries ``ixx``... (symmetric), or gz names (``xUabsU=-7``).

        A gz name that gz-sim pairs by symmetry in our presets is *not* mirrored: set
        ``yDotV`` and ``zDotW`` separately if both should change.
        """
        changes: dict[str, Any] = {}
        hydro = dict(self.hydro)
        inertia = self.inertia.copy()
        for name, val in params.items():
            try:
                fv = float(val)
            except (TypeError, ValueError):
                raise ConfigError(
                    f"vehicle parameter {name} must be a number, got {val!r}"
                ) from None
            if name in _INERTIA_INDEX:
                i, j = _INERTIA_INDEX[name]
                inertia[i, j] = inertia[j, i] = fv
                changes["inertia"] = inertia
            elif name in SCALAR_PARAMETERS:
                changes[name] = fv
            else:
                classify_hydro_name(name)
                hydro[name] = fv
        return replace(self, hydro=hydro, **changes)


_INERTIA_INDEX = {
    "ixx": (0, 0),
    "iyy": (1, 1),
    "izz": (2, 2),
    "ixy": (0, 1),
    "ixz": (0, 2),
    "iyz": (1, 2),
}


# ---------------------------------------------------------------------- TOML files
def vehicle_from_mapping(doc: dict[str, Any], *, source: str = "") -> Vehicle:
    """Build a vehicle from a parsed TOML table (format in :func:`load_vehicle_toml`)."""
    where = source or "vehicle table"
    known = {
        "name",
        "description",
        "mass",
        "inertia",
        "volume",
        "center_of_buoyancy",
        "water_density",
        "gravity",
        "default_current",
        "hydrodynamics",
        "notes",
    }
    for key in doc:
        if key not in known:
            raise ConfigError(f"{where}: unknown key {key!r} (known: {', '.join(sorted(known))})")
    if "mass" not in doc:
        raise ConfigError(f"{where}: missing parameter 'mass' (kg)")
    if "inertia" not in doc:
        raise ConfigError(f"{where}: missing parameter 'inertia' (a list ixx, iyy, izz or a table)")
    inertia = _parse_inertia(doc["inertia"], where)
    vol = doc.get("volume", "neutral")
    volume: float | None
    if vol == "neutral":
        volume = None
    elif isinstance(vol, (int, float)) and not isinstance(vol, bool):
        volume = float(vol)
    else:
        raise ConfigError(f'{where}: volume must be a number (m^3) or "neutral", got {vol!r}')
    hydro = doc.get("hydrodynamics", {})
    if not isinstance(hydro, dict):
        raise ConfigError(f"{where}: 'hydrodynamics' must be a table of gz parameter names")
    for k, val in hydro.items():
        if isinstance(val, bool) or not isinstance(val, (int, float)):
            raise ConfigError(f"{where}: hydrodynamics parameter {k} must be a number, got {val!r}")
    try:
        return Vehicle(
            name=str(doc.get("name", Path(source).stem if source else "vehicle")),
            mass=_number(doc["mass"], "mass", where),
            inertia=inertia,
            volume=volume,
            center_of_buoyancy=_vec3(
                doc.get("center_of_buoyancy", [0, 0, 0]), "center_of_buoyancy", where
            ),
            hydro={k: float(v) for k, v in hydro.items()},
            water_density=_number(
                doc.get("water_density", DEFAULT_WATER_DENSITY), "water_density", where
            ),
            gravity=_number(doc.get("gravity", DEFAULT_GRAVITY), "gravity", where),
            default_current=_vec3(doc.get("default_current", [0, 0, 0]), "default_current", where),
            source=source,
            notes=tuple(doc.get("notes", ())),
        )
    except ConfigError as exc:
        msg = str(exc)
        raise ConfigError(msg if where in msg else f"{where}: {msg}") from None


def read_toml(path: Path, what: str) -> dict[str, Any]:
    """Parse a TOML file; a missing file, unreadable file or bad TOML is a ConfigError that
    names the file (``what`` says which kind, e.g. "vehicle file")."""
    try:
        return tomllib.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ConfigError(f"{what} {path} does not exist") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{what} {path}: cannot read it: {exc}") from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: invalid TOML: {exc}") from None


def load_vehicle_toml(path: str | Path) -> Vehicle:
    """Read a vehicle TOML file.

    Format (units: kg, kg m^2, m^3, m, m/s; body FLU about the CoG; gz-sim names and SNAME sign)::

        name = "tethys"
        mass = 147.8671
        inertia = [3.0, 41.98, 41.98]        # ixx iyy izz, or {ixx=.., iyy=.., izz=.., ixy=..}
        volume = "neutral"                   # or m^3
        center_of_buoyancy = [0.0, 0.0, 0.0] # m from the CoG, body FLU
        water_density = 1000.0
        gravity = 9.8
        [hydrodynamics]
        xDotU = -4.876161
        xUabsU = -6.2282
    """
    p = Path(path)
    return vehicle_from_mapping(read_toml(p, "vehicle file"), source=str(p))


def _number(val: Any, key: str, where: str) -> float:
    if isinstance(val, bool) or not isinstance(val, (int, float)):
        raise ConfigError(f"{where}: parameter {key!r} must be a number, got {val!r}")
    return float(val)


def _vec3(val: Any, key: str, where: str) -> F64:
    if not isinstance(val, (list, tuple)) or len(val) != 3:
        raise ConfigError(f"{where}: parameter {key!r} must be a list of 3 numbers, got {val!r}")
    return np.array([_number(x, key, where) for x in val], dtype=np.float64)


def _parse_inertia(val: Any, where: str) -> F64:
    if isinstance(val, (list, tuple)):
        if len(val) == 3:
            return np.diag([_number(x, "inertia", where) for x in val])
        if len(val) == 6:
            ixx, iyy, izz, ixy, ixz, iyz = (_number(x, "inertia", where) for x in val)
            return np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]])
        raise ConfigError(f"{where}: inertia must have 3 (diagonal) or 6 entries, got {len(val)}")
    if isinstance(val, dict):
        for k in val:
            if k not in _INERTIA_INDEX:
                raise ConfigError(f"{where}: unknown inertia entry {k!r} (ixx iyy izz ixy ixz iyz)")
        for k in ("ixx", "iyy", "izz"):
            if k not in val:
                raise ConfigError(f"{where}: missing parameter 'inertia.{k}'")
        m = np.zeros((3, 3))
        for k, (i, j) in _INERTIA_INDEX.items():
            m[i, j] = m[j, i] = _number(val.get(k, 0.0), f"inertia.{k}", where)
        return m
    raise ConfigError(f"{where}: inertia must be a list or a table, got {val!r}")
