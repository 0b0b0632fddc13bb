"""How far the choice of the Gazebo model moves the pose: one reference input, one run per
model variant, each compared with the baseline run.

The reference input is the default experiment's held teleop keys (surge, heave, sway; yaw,
roll, pitch) at one force and torque level, under an eastward current. Each variant flips one
field of the baseline :class:`~uwval.simulator.model.GazeboModel`: the Coriolis entries (fixed
or legacy), the added-mass scheme (implicit or explicit) and the added-mass Coriolis sign
(Fossen's -C_A or the plugin's +C_A). docs/simulator.md ("sensitivity.json") gives the schema
that :meth:`SensitivityReport.to_dict` and :func:`write_sensitivity` produce.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from uwval.errors import ConfigError
from uwval.rotations import geodesic_angle, rpy_from_quat
from uwval.simulator.engine import SimResult, simulate
from uwval.simulator.errors import DivergenceError, SimulationError
from uwval.simulator.inputs import Constant, InputProfile, KeyScript
from uwval.simulator.model import (
    FLUID_ADDED_MASS,
    AddedMass,
    CaSign,
    CoriolisEntries,
    GazeboModel,
)
from uwval.simulator.presets import load_vehicle
from uwval.simulator.vehicle import Vehicle

SCHEMA = "uwval-sensitivity/1"
#: The default experiment's held keys (data/experiments/default.toml), seconds of sim time.
FORCE_KEYS = "i@0.2:1.2; t@1.0:1.8; J@1.6:2.6"
TORQUE_KEYS = "j@0.4:1.4; u@1.6:2.2; y@2.4:3.0"
PUBLISH_RATE_HZ = 50.0


@dataclass(frozen=True)
class ReferenceInput:
    """The input every variant runs: held keys at ``force_n`` N / ``torque_nm`` N m (body FLU)
    and a constant current of ``current_ms`` m/s towards world +x (east)."""

    force_n: float
    torque_nm: float
    current_ms: float

    def profile(self) -> InputProfile:
        """The input as the simulator takes it."""
        force = KeyScript.parse(FORCE_KEYS, force_step=self.force_n, torque_step=self.torque_nm)
        torque = KeyScript.parse(TORQUE_KEYS, force_step=self.force_n, torque_step=self.torque_nm)
        current = Constant(np.array([self.current_ms, 0.0, 0.0]))
        return InputProfile(force.channel(0), torque.channel(1), current, "body")

    def to_dict(self) -> dict[str, Any]:
        """JSON form (schema in docs/simulator.md)."""
        return {
            "keys": f"{FORCE_KEYS}; {TORQUE_KEYS}",
            "force_n": self.force_n,
            "torque_nm": self.torque_nm,
            "current_ms": self.current_ms,
            "current_axis": "x",
        }


@dataclass(frozen=True)
class VariantShift:
    """How far one model variant's run is from the baseline's (m, degrees).

    The five distances are None when the variant diverged (``diverged_at_s`` then says when)."""

    name: str
    label: str
    model: GazeboModel
    diverged_at_s: float | None = None
    position_max_m: float | None = None
    position_final_m: float | None = None
    yaw_max_deg: float | None = None
    yaw_final_deg: float | None = None
    rotation_max_deg: float | None = None

    @property
    def diverged(self) -> bool:
        """The variant's run diverged (no distances)."""
        return self.diverged_at_s is not None

    def to_dict(self) -> dict[str, Any]:
        """JSON form (schema in docs/simulator.md)."""
        model = self.model.to_dict()
        return {
            "name": self.name,
            "label": self.label,
            "model": {k: model[k] for k in ("coriolis", "added_mass", "ca_sign")},
            "diverged": self.diverged,
            "diverged_at_s": self.diverged_at_s,
            "position_max_m": self.position_max_m,
            "position_final_m": self.position_final_m,
            "yaw_max_deg": self.yaw_max_deg,
            "yaw_final_deg": self.yaw_final_deg,
            "rotation_max_deg": self.rotation_max_deg,
        }


@dataclass(frozen=True)
class SensitivityReport:
    """The baseline and the shift of each variant (see :func:`model_sensitivity`)."""

    vehicle: str
    vehicle_source: str
    duration_s: float
    dt_s: float
    reference_input: ReferenceInput
    baseline: GazeboModel
    baseline_label: str
    variants: tuple[VariantShift, ...]

    def to_dict(self) -> dict[str, Any]:
        """The sensitivity.json document (schema ``uwval-sensitivity/1``)."""
        base = self.baseline.to_dict()
        return {
            "schema": SCHEMA,
            "vehicle": self.vehicle,
            "vehicle_source": self.vehicle_source,
            "duration_s": self.duration_s,
            "dt_s": self.dt_s,
            "publish_rate_hz": PUBLISH_RATE_HZ,
            "reference_input": self.reference_input.to_dict(),
            "baseline": {
                **{k: base[k] for k in ("coriolis", "added_mass", "ca_sign")},
                "label": self.baseline_label,
            },
            "variants": [v.to_dict() for v in self.variants],
        }


def _variants(baseline: GazeboModel) -> list[tuple[str, str, GazeboModel]]:
    """The three one-field flips of ``baseline``: (name, label, model)."""
    legacy = baseline.coriolis is CoriolisEntries.FIXED
    explicit = baseline.added_mass is AddedMass.IMPLICIT
    gazebo_sign = baseline.ca_sign is CaSign.FOSSEN
    return [
        (
            "coriolis",
            "Coriolis entries of gz-sim 8.0-8.11 / 9.x / 10.0-10.1"
            if legacy
            else "Coriolis entries of gz-sim 8.12+ / 10.2+",
            replace(baseline, coriolis=CoriolisEntries.LEGACY if legacy else CoriolisEntries.FIXED),
        ),
        (
            "added_mass",
            "added mass as the Hydrodynamics plugin applies it (explicit backward difference)"
            if explicit
            else "added mass in the mass matrix (implicit, as <fluid_added_mass>)",
            replace(baseline, added_mass=AddedMass.EXPLICIT if explicit else AddedMass.IMPLICIT),
        ),
        (
            "ca_sign",
            "added-mass Coriolis with the Hydrodynamics plugin's sign (+C_A)"
            if gazebo_sign
            else "added-mass Coriolis with Fossen's sign (-C_A)",
            replace(baseline, ca_sign=CaSign.GAZEBO if gazebo_sign else CaSign.FOSSEN),
        ),
    ]


def _shift(name: str, label: str, model: GazeboModel, base: SimResult, run: SimResult) -> Any:
    """The distances between a variant's run and the baseline's, tick by tick."""
    dpos = np.linalg.norm(run.vehicle.position - base.vehicle.position, axis=1)
    yaw_b = rpy_from_quat(base.vehicle.orientation)[:, 2]
    yaw_v = rpy_from_quat(run.vehicle.orientation)[:, 2]
    dyaw = np.degrees(np.abs(np.angle(np.exp(1j * (yaw_v - yaw_b)))))  # wrapped to [0, 180]
    drot = np.degrees(geodesic_angle(run.vehicle.orientation, base.vehicle.orientation))
    return VariantShift(
        name,
        label,
        model,
        position_max_m=float(dpos.max()),
        position_final_m=float(dpos[-1]),
        yaw_max_deg=float(dyaw.max()),
        yaw_final_deg=float(dyaw[-1]),
        rotation_max_deg=float(drot.max()),
    )


def model_sensitivity(
    vehicle: Vehicle | str = "bluerov2_heavy",
    *,
    duration_s: float = 4.0,
    force_n: float = 10.0,
    torque_nm: float = 0.25,
    current_ms: float = 0.1,
    baseline: GazeboModel | None = None,
    dt: float = 1e-3,
) -> SensitivityReport:
    """Run the reference input under ``baseline`` (None: the default experiment's model,
    BlueROV2 Heavy with ``<fluid_added_mass>``) and under each one-field variant of it; return
    how far each variant's vehicle pose moves from the baseline's (position m, yaw and
    geodesic angle degrees, largest over the run and at its end).

    ``vehicle`` is a :class:`Vehicle` or anything :func:`load_vehicle` takes. A variant that
    diverges is reported as diverged, with no distances; a diverging baseline is an error.
    """
    if not (math.isfinite(duration_s) and duration_s > 0):
        raise ConfigError(f"sensitivity: duration_s must be > 0 s, got {duration_s}")
    for what, val in (("force_n", force_n), ("torque_nm", torque_nm), ("current_ms", current_ms)):
        if not math.isfinite(val):
            raise ConfigError(f"sensitivity: {what} must be a finite number, got {val}")
    veh = vehicle if isinstance(vehicle, Vehicle) else load_vehicle(vehicle)
    base_model = FLUID_ADDED_MASS if baseline is None else baseline
    ref = ReferenceInput(float(force_n), float(torque_nm), float(current_ms))
    inputs = ref.profile()

    def run(model: GazeboModel) -> SimResult:
        return simulate(veh, inputs, duration_s, dt=dt, publish_rate=PUBLISH_RATE_HZ, model=model)

    try:
        base = run(base_model)
    except DivergenceError as exc:
        raise SimulationError(f"sensitivity: the baseline model diverged: {exc}") from None
    shifts: list[VariantShift] = []
    for name, label, model in _variants(base_model):
        try:
            shifts.append(_shift(name, label, model, base, run(model)))
        except DivergenceError as exc:
            shifts.append(VariantShift(name, label, model, diverged_at_s=round(exc.at_s, 6)))
    return SensitivityReport(
        vehicle=veh.name,
        vehicle_source=veh.source,
        duration_s=float(duration_s),
        dt_s=float(dt),
        reference_input=ref,
        baseline=base_model,
        baseline_label=(
            "the default experiment's model"
            if base_model == FLUID_ADDED_MASS
            else "the model given"
        ),
        variants=tuple(shifts),
    )


def write_sensitivity(report: SensitivityReport, path: str | Path) -> Path:
    """Write ``report`` as sensitivity.json (indented JSON, schema in docs/simulator.md)."""
    out = Path(path)
    try:
        out.write_text(json.dumps(report.to_dict(), indent=2) + "\n")
    except OSError as exc:
        raise ConfigError(f"{out}: cannot write the sensitivity table: {exc.strerror}") from None
    return out
