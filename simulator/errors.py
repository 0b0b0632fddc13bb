"""Errors of the simulator (:mod:`uwval.simulator`)."""

from __future__ import annotations

from uwval.errors import UwvalError


class SimulationError(UwvalError):
    """The simulator cannot run (bad parameters, divergence)."""
