"""Optional thrusters: per-thruster thrust commands mapped to the body wrench they produce.

Each thruster has a position (m, body FLU, from the CoG) and a unit thrust direction (body
FLU); thrust ``T_i`` (N) gives force ``T_i d_i`` and moment ``r_i x T_i d_i``. The 6 x n
allocation matrix ``B`` maps thrusts to the wrench, ``tau = B T``; :meth:`Thrusters.inputs`
turns thrust signals into an :class:`~uwval.simulator.inputs.InputProfile` (body-frame wrench), so
thruster-driven runs go through the same :func:`~uwval.simulator.simulate` path.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from uwval.errors import ConfigError
from uwval.simulator.inputs import ZERO, InputProfile, Signal

F64 = NDArray[np.float64]


@dataclass(frozen=True)
class Thrusters:
    """Thruster layout: ``positions`` (n, 3) m, ``directions`` (n, 3) unit vectors, body FLU."""

    positions: F64
    directions: F64

    def __post_init__(self) -> None:
        pos = np.asarray(self.positions, dtype=np.float64).reshape(-1, 3)
        d = np.asarray(self.directions, dtype=np.float64).reshape(-1, 3)
        if pos.shape != d.shape or pos.shape[0] == 0:
            raise ConfigError("thrusters need as many positions as directions (n x 3 each)")
        norms = np.linalg.norm(d, axis=1)
        if np.any(norms < 1e-9):
            raise ConfigError(f"thruster {int(np.argmin(norms))} has a zero thrust direction")
        object.__setattr__(self, "positions", pos)
        object.__setattr__(self, "directions", d / norms[:, None])

    @property
    def allocation(self) -> F64:
        """6 x n matrix B with wrench = B @ thrusts (force N; moment N m about the CoG)."""
        b = np.empty((6, self.positions.shape[0]))
        b[:3] = self.directions.T
        b[3:] = np.cross(self.positions, self.directions).T
        return b

    def wrench(self, thrusts: ArrayLike) -> F64:
        """(k, n) thrusts (N) -> (k, 6) body wrenches (vectorised over k)."""
        t = np.atleast_2d(np.asarray(thrusts, dtype=np.float64))
        if t.shape[1] != self.positions.shape[0]:
            raise ConfigError(f"expected {self.positions.shape[0]} thrust values, got {t.shape[1]}")
        out: F64 = t @ self.allocation.T
        return out

    def inputs(self, thrusts: Sequence[Signal], current: Signal = ZERO) -> InputProfile:
        """An input profile from one scalar-valued signal per thruster (component 0 = thrust N)."""
        if len(thrusts) != self.positions.shape[0]:
            raise ConfigError(
                f"expected {self.positions.shape[0]} thrust signals, got {len(thrusts)}"
            )
        sig = _ThrustWrench(self, tuple(thrusts))
        return InputProfile(_Part(sig, 0), _Part(sig, 1), current, "body")


@dataclass(frozen=True)
class _ThrustWrench:
    thrusters: Thrusters
    thrusts: tuple[Signal, ...]

    def __call__(self, t: F64) -> F64:
        cols = np.stack([s(t)[:, 0] for s in self.thrusts], axis=1)
        return self.thrusters.wrench(cols)


@dataclass(frozen=True)
class _Part:
    source: _ThrustWrench
    which: int  # 0 force, 1 torque

    def __call__(self, t: F64) -> F64:
        w = self.source(np.asarray(t, dtype=np.float64))
        return w[:, 3 * self.which : 3 * self.which + 3]

    def is_zero(self) -> bool:
        return all(s.is_zero() for s in self.source.thrusts)
