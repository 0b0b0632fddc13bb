"""Which Gazebo: the variants of gz-sim's underwater model that uwval's kernel reproduces.

A :class:`GazeboModel` names one configuration of the equations in
:mod:`uwval.simulator.dynamics`. Each field is one documented difference between gz-sim
releases or configurations (docs/simulator.md, "Sources"):

* ``coriolis``: gz-sim 8.12+ / 10.2+ (``FIXED``) or the two wrong added-mass Coriolis entries of
  8.0-8.11, 9.x and 10.0-10.1 (``LEGACY``).
* ``added_mass``: the Hydrodynamics plugin's backward difference (``EXPLICIT``, stable only when
  |X_udot| < m per axis) or the added mass in the mass matrix (``IMPLICIT``, as gz-physics' DART
  applies SDFormat's ``<fluid_added_mass>``).
* ``ca_sign``: the added-mass Coriolis wrench with the plugin's sign (``GAZEBO``, ``+C_A nu_r``)
  or Fossen's / Kirchhoff's (``FOSSEN``, ``-C_A nu_r``, what a rigid body whose spatial inertia
  includes the added mass feels).
* ``zero_prev_state``: gz-sim 8.0-8.11 starts the backward difference from a zero twist (an
  added-mass kick on the first step when a current flows).
* ``int_abs_damping``: the quadratic damping's ``|v|`` truncated to an integer. An emulation of
  a reading of gz-sim 8.0-8.11's unqualified ``abs()`` that real builds very likely never
  showed: Hydrodynamics.cc includes Eigen and protobuf headers that bring ``<stdlib.h>`` and
  its double overload (issue 31, point 5). Off unless asked for by its own option.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from enum import Enum
from typing import Any


class CoriolisEntries(str, Enum):
    """gz-sim's added-mass Coriolis matrix: as fixed in 8.12+ / 10.2+, or the legacy entries."""

    FIXED = "fixed"
    LEGACY = "legacy"

    def __str__(self) -> str:
        return self.value


class AddedMass(str, Enum):
    """How the added mass enters: the plugin's explicit backward difference, or the mass matrix."""

    EXPLICIT = "explicit"
    IMPLICIT = "implicit"

    def __str__(self) -> str:
        return self.value


class CaSign(str, Enum):
    """The sign of the added-mass Coriolis wrench: gz's plugin (+C_A) or Fossen's (-C_A)."""

    GAZEBO = "gazebo"
    FOSSEN = "fossen"

    def __str__(self) -> str:
        return self.value


@dataclass(frozen=True)
class GazeboModel:
    """One configuration of gz-sim's underwater equations (see the module docstring).

    The default is the Hydrodynamics plugin exactly as gz-sim 8.12+ codes it, with its added
    mass given as plugin parameters (``xDotU`` ...), as gz-sim's Tethys example runs.
    """

    coriolis: CoriolisEntries = CoriolisEntries.FIXED
    added_mass: AddedMass = AddedMass.EXPLICIT
    ca_sign: CaSign = CaSign.GAZEBO
    zero_prev_state: bool = False
    int_abs_damping: bool = False

    def __post_init__(self) -> None:
        # accept the enums' string values (TOML, JSON, CLI) and store the enums
        object.__setattr__(self, "coriolis", CoriolisEntries(self.coriolis))
        object.__setattr__(self, "added_mass", AddedMass(self.added_mass))
        object.__setattr__(self, "ca_sign", CaSign(self.ca_sign))

    @property
    def implicit(self) -> bool:
        """Added mass in the mass matrix."""
        return self.added_mass is AddedMass.IMPLICIT

    @property
    def legacy_coriolis(self) -> bool:
        """The legacy Coriolis entries of gz-sim 8.0-8.11 / 9.x / 10.0-10.1."""
        return self.coriolis is CoriolisEntries.LEGACY

    @property
    def fossen(self) -> bool:
        """Fossen's -C_A sign."""
        return self.ca_sign is CaSign.FOSSEN

    @property
    def legacy_gz8(self) -> bool:
        """Both documented gz-sim 8.0-8.11 differences: legacy Coriolis and zero prevState."""
        return self.legacy_coriolis and self.zero_prev_state

    def as_legacy_gz8(self) -> GazeboModel:
        """This model as gz-sim 8.0-8.11 runs it: its Coriolis entries and its zero prevState
        (not the int abs(), which real builds very likely never had)."""
        return replace(self, coriolis=CoriolisEntries.LEGACY, zero_prev_state=True)

    def to_dict(self) -> dict[str, Any]:
        """JSON form: enum values as strings."""
        return {
            "coriolis": self.coriolis.value,
            "added_mass": self.added_mass.value,
            "ca_sign": self.ca_sign.value,
            "zero_prev_state": self.zero_prev_state,
            "int_abs_damping": self.int_abs_damping,
        }


#: The Hydrodynamics plugin as gz-sim 8.12+ codes it (added mass as plugin parameters).
PLUGIN_ADDED_MASS = GazeboModel()
#: The added mass as SDFormat ``<fluid_added_mass>`` (gz-sim 8 / Harmonic with gz-physics 7's
#: DART): in the mass matrix, its Coriolis with the rigid body's (Kirchhoff) sign; the plugin
#: keeps only damping and current. The default experiment's model.
FLUID_ADDED_MASS = GazeboModel(added_mass=AddedMass.IMPLICIT, ca_sign=CaSign.FOSSEN)
