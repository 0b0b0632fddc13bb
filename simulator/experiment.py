"""Experiments: factorial designs over force, torque, current and vehicle parameters.

An experiment TOML file::

    name = "default"              # used in run names
    vehicle = "tethys"            # preset name, .sdf or .toml path (relative to this file)
    duration_s = 10.0             # sim seconds per run
    seed = 0                      # base seed; run i of the design gets seed + i
    repeats = 1                   # runs per factor combination
    publish_rate = 50.0           # Hz (optional)
    dt = 0.001                    # s (optional)
    added_mass = "explicit"       # optional: "explicit" (plugin) or "implicit" (mass matrix)
    coriolis = "fixed"            # optional: "fixed" (gz-sim 8.12+) or "legacy" (8.0-8.11)
    ca_sign = "gazebo"            # optional: "gazebo" (+C_A, the plugin) or "fossen" (-C_A)
    legacy_gz8 = false            # optional: gz-sim 8.0-8.11 (legacy Coriolis, zero prevState)
    int_abs_damping = false       # optional: emulated int abs() (docs/simulator.md: unlikely)
    # (implicit_added_mass = true / legacy_coriolis = true: the older spellings, still read)
    wrench_frame = "body"         # optional: "body" (FLU) or "world" (ENU)

    [baseline]                    # optional inputs every run gets (added to the factors')
    force = [0.0, 0.0, 0.0]       # a 3-vector, or a profile table:
    current = {kind = "ramp", value = [0.1, 0.0, 0.0], t0 = 0.0, t1 = 5.0}
    keys = "i@0:5; j@2:3"         # optional teleop key script (hold key = wrench increment)

    [unity]                       # optional: the Unity side of every run (uwval.bridge
    transport = "real-endpoint"   # .unity_model; the keys of uwval simulate's options):
    frame_model = "vsync"         # transport, frame_model, frame_rate, stall_prob,
    float32 = true                # frame_trace (path relative to this file), float32,
    clock_drift_ppm = 20.0        # clock_drift_ppm, clock_offset_s, latency_s, jitter_s,
                                  # drop_prob, unity_map; they override the command line

    [factors.force]               # kind is the table name: force | torque | current
    axis = "x"                    # x | y | z (body FLU for force/torque, world ENU for current)
    levels = [5.0, 10.0]          # N (force), N m (torque), m/s (current)
    profile = {kind = "step", t0 = 1.0}   # optional: constant (default), step, ramp, pulse;
                                          # the level scales the profile's unit vector

    [factors.torque]
    keys = "j@1:2; u@2:3"         # or held teleop keys (teleop_wrench_keyboard): while a key
    levels = [0.5, 1.0]           # is held its axis gets the level (N or N m); force
                                  # factors take force keys, torque factors torque keys

    [factors.xUabsU]              # any vehicle parameter: mass, volume, ixx..., gz names
    levels = [-6.2282, -10.0]

    [factors.vehicle]             # or whole vehicles
    levels = ["tethys", "bluerov2_heavy_stable"]

A factor table may instead name its kind with ``kind = "force"`` and any table name (two force
factors on different axes, say). The design is the full factorial of all levels x repeats, in
a stable order. Run names are filesystem-safe and unique (``<name>-<index>-<factor=level>...``).
"""

from __future__ import annotations

import itertools
import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from uwval.errors import ConfigError
from uwval.simulator.inputs import (
    TELEOP_KEYS,
    Constant,
    InputProfile,
    KeyScript,
    Signal,
    Sum,
    signal_from_spec,
)
from uwval.simulator.model import (
    PLUGIN_ADDED_MASS,
    AddedMass,
    CaSign,
    CoriolisEntries,
    GazeboModel,
)
from uwval.simulator.presets import load_vehicle
from uwval.simulator.vehicle import (
    SCALAR_PARAMETERS,
    Vehicle,
    classify_hydro_name,
    read_toml,
)

_WRENCH_KINDS = ("force", "torque", "current")
_AXES = {"x": 0, "y": 1, "z": 2}
_INERTIA = ("ixx", "iyy", "izz", "ixy", "ixz", "iyz")


@dataclass(frozen=True)
class RunSpec:
    """One run of an experiment.

    Attributes:
        name: filesystem-safe, unique within the experiment.
        factors: factor name -> level (float, or str for a ``vehicle`` factor); JSON scalars.
        vehicle: the vehicle with any parameter factors applied.
        inputs: force/torque (wrench frame) and world current profiles.
        duration_s, seed, publish_rate, dt: run settings.
        model: which gz-sim configuration the physics reproduces.
        repeat: repeat index (0-based).
    """

    name: str
    factors: dict[str, float | str]
    vehicle: Vehicle
    inputs: InputProfile
    duration_s: float
    seed: int
    publish_rate: float = 50.0
    dt: float = 1e-3
    model: GazeboModel = PLUGIN_ADDED_MASS
    repeat: int = 0

    def simulate_kwargs(self) -> dict[str, Any]:
        """Keyword arguments of :func:`uwval.simulator.simulate` but vehicle, inputs, duration."""
        return {
            "dt": self.dt,
            "publish_rate": self.publish_rate,
            "seed": self.seed,
            "model": self.model,
        }


@dataclass(frozen=True)
class Factor:
    """One experiment factor: a name, a kind and its levels."""

    name: str
    kind: str  # force | torque | current | vehicle | param
    levels: tuple[float | str, ...]
    axis: int = 0
    profile: dict[str, Any] = field(default_factory=dict)
    keys: str = ""


@dataclass
class Experiment:
    """A parsed experiment file (format in the module docstring)."""

    name: str
    vehicle: Vehicle
    factors: list[Factor]
    duration_s: float = 10.0
    seed: int = 0
    repeats: int = 1
    publish_rate: float = 50.0
    dt: float = 1e-3
    model: GazeboModel = PLUGIN_ADDED_MASS
    wrench_frame: str = "body"
    baseline: dict[str, Signal] = field(default_factory=dict)
    unity: dict[str, Any] = field(default_factory=dict)
    source: str = ""
    base_dir: Path = field(default_factory=Path.cwd)

    def runs(self) -> list[RunSpec]:
        """The full factorial design x repeats, in a stable order."""
        combos = (
            list(itertools.product(*(f.levels for f in self.factors))) if self.factors else [()]
        )
        out: list[RunSpec] = []
        idx = 0
        width = max(2, len(str(len(combos) * self.repeats - 1)))
        for combo in combos:
            for rep in range(self.repeats):
                out.append(self._run(idx, width, combo, rep))
                idx += 1
        names = [r.name for r in out]
        assert len(set(names)) == len(names), "run names must be unique"
        return out

    def _run(self, idx: int, width: int, combo: tuple[float | str, ...], rep: int) -> RunSpec:
        vehicle = self.vehicle
        params: dict[str, float] = {}
        sig: dict[str, list[Signal]] = {k: [] for k in _WRENCH_KINDS}
        for k, s in self.baseline.items():
            if k in sig:
                sig[k].append(s)
        factors: dict[str, float | str] = {}
        for f, level in zip(self.factors, combo, strict=True):
            factors[f.name] = level
            if f.kind == "vehicle":
                vehicle = _load_vehicle_rel(str(level), self.base_dir)
            elif f.kind == "param":
                params[f.name] = float(level)
            elif f.keys:
                script = KeyScript.parse(f.keys, force_step=float(level), torque_step=float(level))
                sig[f.kind].append(script.channel(0 if f.kind == "force" else 1))
            else:
                unit = np.zeros(3)
                unit[f.axis] = 1.0
                spec = dict(f.profile)
                spec["value"] = (unit * float(level)).tolist()
                sig[f.kind].append(signal_from_spec(spec, f"factor {f.name} profile"))
        if params:
            vehicle = vehicle.with_params(**params)
        if "keys" in self.baseline:
            ks = self.baseline["keys"]
            assert isinstance(ks, Sum)
            sig["force"].append(ks.parts[0])
            sig["torque"].append(ks.parts[1])

        def total(parts: list[Signal]) -> Signal:
            if not parts:
                return Constant(np.zeros(3))
            return parts[0] if len(parts) == 1 else Sum(tuple(parts))

        inputs = InputProfile(
            total(sig["force"]), total(sig["torque"]), total(sig["current"]), self.wrench_frame
        )
        label = "_".join(f"{k}={_fmt(v)}" for k, v in factors.items())
        name = _safe(
            f"{self.name}-{idx:0{width}d}"
            + (f"-{label}" if label else "")
            + (f"-r{rep}" if self.repeats > 1 else "")
        )
        return RunSpec(
            name=name,
            factors=factors,
            vehicle=vehicle,
            inputs=inputs,
            duration_s=self.duration_s,
            seed=self.seed + idx,
            publish_rate=self.publish_rate,
            dt=self.dt,
            model=self.model,
            repeat=rep,
        )


def _fmt(v: float | str) -> str:
    if isinstance(v, str):
        return v
    return f"{v:g}"


def _safe(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9._=+-]", "_", name)


def _load_vehicle_rel(name: str, base: Path) -> Vehicle:
    p = Path(name)
    if not p.is_absolute() and (base / p).exists():
        return load_vehicle((base / p).resolve())  # no "../" in the recorded source
    return load_vehicle(name)


def _num(doc: dict[str, Any], key: str, default: float, where: str, positive: bool = True) -> float:
    val = doc.get(key, default)
    if isinstance(val, bool) or not isinstance(val, (int, float)) or not math.isfinite(val):
        raise ConfigError(f"{where}: {key!r} must be a number, got {val!r}")
    if positive and val <= 0:
        raise ConfigError(f"{where}: {key!r} must be > 0, got {val!r}")
    return float(val)


def _bool(doc: dict[str, Any], key: str, where: str) -> bool:
    val = doc.get(key, False)
    if not isinstance(val, bool):
        raise ConfigError(f"{where}: {key!r} must be true or false, got {val!r}")
    return val


def _choice(doc: dict[str, Any], key: str, enum: type[Any], where: str) -> Any:
    """An enum-valued key of the experiment table, or None when absent."""
    if key not in doc:
        return None
    try:
        return enum(doc[key])
    except ValueError:
        options = ", ".join(f'"{m.value}"' for m in enum)
        raise ConfigError(f"{where}: {key!r} must be one of {options}, got {doc[key]!r}") from None


def _model(doc: dict[str, Any], where: str) -> GazeboModel:
    """The experiment's :class:`GazeboModel` from its keys (new spellings win over old)."""
    added = _choice(doc, "added_mass", AddedMass, where)
    if added is None:
        added = AddedMass.IMPLICIT if _bool(doc, "implicit_added_mass", where) else None
    coriolis = _choice(doc, "coriolis", CoriolisEntries, where)
    if coriolis is None and _bool(doc, "legacy_coriolis", where):
        coriolis = CoriolisEntries.LEGACY
    sign = _choice(doc, "ca_sign", CaSign, where)
    if sign is None and _bool(doc, "fossen_coriolis", where):
        sign = CaSign.FOSSEN
    model = GazeboModel(
        coriolis=coriolis or CoriolisEntries.FIXED,
        added_mass=added or AddedMass.EXPLICIT,
        ca_sign=sign or CaSign.GAZEBO,
        int_abs_damping=_bool(doc, "int_abs_damping", where),
    )
    return model.as_legacy_gz8() if _bool(doc, "legacy_gz8", where) else model


def _factor(name: str, spec: Any, where: str) -> Factor:
    # No square brackets: the CLI prints messages through rich, which reads "[x]" as markup.
    fw = f"{where}: factor table factors.{name}"
    if not isinstance(spec, dict):
        raise ConfigError(f"{fw} must be a table with 'levels'")
    kind = spec.get("kind", name)
    if kind not in (*_WRENCH_KINDS, "vehicle"):
        # any vehicle parameter
        pname = kind
        if pname not in SCALAR_PARAMETERS and pname not in _INERTIA:
            try:
                classify_hydro_name(pname)
            except ConfigError:
                raise ConfigError(
                    f"{fw}: unknown factor kind {pname!r}: use force, torque, current, vehicle, "
                    "or a vehicle parameter (mass, volume, water_density, gravity, ixx..., or a "
                    "gz-sim name such as xUabsU)"
                ) from None
        kind = "param"
    allowed = (
        {"kind", "levels", "axis", "profile", "keys"}
        if kind in _WRENCH_KINDS
        else {"kind", "levels"}
    )
    extra = set(spec) - allowed
    if extra:
        raise ConfigError(f"{fw}: unknown key(s) {sorted(extra)} (allowed: {sorted(allowed)})")
    levels = spec.get("levels")
    if not isinstance(levels, list) or not levels:
        raise ConfigError(f"{fw}: 'levels' must be a non-empty list")
    for lv in levels:
        if kind == "vehicle":
            if not isinstance(lv, str):
                raise ConfigError(f"{fw}: vehicle levels must be names or paths, got {lv!r}")
        elif isinstance(lv, bool) or not isinstance(lv, (int, float)) or not math.isfinite(lv):
            raise ConfigError(f"{fw}: levels must be numbers, got {lv!r}")
    if len(set(levels)) != len(levels):
        raise ConfigError(f"{fw}: duplicate levels {levels}")
    axis = 0
    profile: dict[str, Any] = {}
    keys = spec.get("keys", "")
    if "keys" in spec:
        if kind not in ("force", "torque"):
            raise ConfigError(f"{fw}: 'keys' drives a force or torque factor, not {kind}")
        if "axis" in spec or "profile" in spec:
            raise ConfigError(f"{fw}: give either 'keys' or 'axis'/'profile', not both")
        if not isinstance(keys, str):
            raise ConfigError(f"{fw}: 'keys' must be a key script like \"i@0:5; j@2:3\"")
        try:
            script = KeyScript.parse(keys)
        except ConfigError as exc:
            raise ConfigError(f"{fw}: keys: {exc}") from None
        want = 0 if kind == "force" else 1
        wrong = [kp.key for kp in script.presses if TELEOP_KEYS[kp.key][0] != want]
        if wrong or not script.presses:
            raise ConfigError(
                f"{fw}: keys must hold {kind} keys only"
                + (f"; {' '.join(wrong)} drive the other channel" if wrong else "")
            )
    elif kind in _WRENCH_KINDS:
        ax = spec.get("axis", "x")
        if ax not in _AXES:
            raise ConfigError(f"{fw}: axis must be x, y or z, got {ax!r}")
        axis = _AXES[ax]
        profile = spec.get("profile", {})
        if not isinstance(profile, dict) or "value" in profile:
            raise ConfigError(f"{fw}: 'profile' must be a table without 'value' (the level is)")
        # validate now, with a unit value
        signal_from_spec({**profile, "value": [1.0, 0.0, 0.0]}, f"{fw} profile")
    conv: tuple[float | str, ...] = tuple(lv if isinstance(lv, str) else float(lv) for lv in levels)
    return Factor(name=name, kind=kind, levels=conv, axis=axis, profile=profile, keys=keys)


def experiment_from_mapping(
    doc: dict[str, Any], *, source: str = "", base_dir: Path | None = None
) -> Experiment:
    """Build an experiment from a parsed TOML table."""
    where = source or "experiment"
    known = {
        "name", "description", "vehicle", "duration_s", "seed", "repeats", "publish_rate", "dt",
        "implicit_added_mass", "legacy_coriolis", "wrench_frame", "baseline", "factors",
        "unity", "legacy_gz8", "added_mass", "coriolis", "ca_sign", "int_abs_damping",
        "fossen_coriolis",
    }  # fmt: skip
    extra = set(doc) - known
    if extra:
        raise ConfigError(f"{where}: unknown key(s) {sorted(extra)} (known: {sorted(known)})")
    base = base_dir if base_dir is not None else Path.cwd()
    vname = doc.get("vehicle", "tethys")
    if not isinstance(vname, str):
        raise ConfigError(f"{where}: 'vehicle' must be a preset name or a path")
    try:
        vehicle = _load_vehicle_rel(vname, base)
    except ConfigError as exc:
        raise ConfigError(f"{where}: vehicle: {exc}") from None
    seed = doc.get("seed", 0)
    repeats = doc.get("repeats", 1)
    for key, val in (("seed", seed), ("repeats", repeats)):
        if (
            isinstance(val, bool)
            or not isinstance(val, int)
            or val < (1 if key == "repeats" else 0)
        ):
            lowest = 1 if key == "repeats" else 0
            raise ConfigError(f"{where}: {key!r} must be an integer >= {lowest}, got {val!r}")
    wf = doc.get("wrench_frame", "body")
    if wf not in ("body", "world"):
        raise ConfigError(f'{where}: \'wrench_frame\' must be "body" or "world", got {wf!r}')
    baseline: dict[str, Signal] = {}
    bdoc = doc.get("baseline", {})
    if not isinstance(bdoc, dict):
        raise ConfigError(f"{where}: 'baseline' must be a table")
    for key, val in bdoc.items():
        if key in _WRENCH_KINDS:
            baseline[key] = signal_from_spec(val, f"{where}: baseline.{key}")
        elif key == "keys":
            if not isinstance(val, str):
                raise ConfigError(f"{where}: baseline.keys must be a key script string")
            try:
                ks = KeyScript.parse(val)
            except ConfigError as exc:
                raise ConfigError(f"{where}: baseline.keys: {exc}") from None
            baseline["keys"] = Sum((ks.channel(0), ks.channel(1)))
        else:
            raise ConfigError(
                f"{where}: unknown baseline key {key!r} (force, torque, current, keys)"
            )
    unity = _unity_table(doc.get("unity", {}), where, base)
    fdoc = doc.get("factors", {})
    if not isinstance(fdoc, dict):
        raise ConfigError(f"{where}: 'factors' must be a table of tables")
    factors = [_factor(k, v, where) for k, v in fdoc.items()]
    name = doc.get("name", Path(source).stem if source else "experiment")
    return Experiment(
        name=_safe(str(name)),
        vehicle=vehicle,
        factors=factors,
        duration_s=_num(doc, "duration_s", 10.0, where),
        seed=int(seed),
        repeats=int(repeats),
        publish_rate=_num(doc, "publish_rate", 50.0, where),
        dt=_num(doc, "dt", 1e-3, where),
        model=_model(doc, where),
        wrench_frame=wf,
        baseline=baseline,
        unity=unity,
        source=source,
        base_dir=base,
    )


#: ``[unity]`` keys -> (SessionOptions field, accepted type).
_UNITY_KEYS: dict[str, tuple[str, type]] = {
    "transport": ("transport", str),
    "frame_model": ("frame_model", str),
    "frame_rate": ("frame_rate", float),
    "stall_prob": ("stall_prob", float),
    "frame_trace": ("frame_trace", str),
    "float32": ("float32", bool),
    "clock_drift_ppm": ("clock_drift_ppm", float),
    "clock_offset_s": ("unity_clock_offset_s", float),
    "latency_s": ("latency_s", float),
    "jitter_s": ("jitter_s", float),
    "drop_prob": ("drop_prob", float),
    "unity_map": ("unity_map", str),
}


def _unity_table(udoc: Any, where: str, base: Path) -> dict[str, Any]:
    """The ``[unity]`` table -> SessionOptions overrides (types checked here, values by the
    bridge when the session options are made)."""
    if not isinstance(udoc, dict):
        raise ConfigError(f"{where}: 'unity' must be a table")
    out: dict[str, Any] = {}
    for key, val in udoc.items():
        if key not in _UNITY_KEYS:
            raise ConfigError(
                f"{where}: unknown key unity.{key} (known: {', '.join(sorted(_UNITY_KEYS))})"
            )
        name, typ = _UNITY_KEYS[key]
        if typ is float:
            ok = isinstance(val, (int, float)) and not isinstance(val, bool)
            ok = ok and math.isfinite(val)
        else:
            ok = isinstance(val, typ)
        if not ok:
            want = {float: "a number", bool: "true or false", str: "a string"}[typ]
            raise ConfigError(f"{where}: unity.{key} must be {want}, got {val!r}")
        if key == "frame_trace":
            p = Path(val)
            val = str(p if p.is_absolute() else base / p)
        out[name] = float(val) if typ is float else val
    return out


def load_experiment(path: str | Path) -> Experiment:
    """Read an experiment TOML file (format in the module docstring)."""
    p = Path(path)
    return experiment_from_mapping(
        read_toml(p, "experiment file"), source=str(p), base_dir=p.parent
    )
