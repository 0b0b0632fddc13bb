"""Errors of the simulator (:mod:`uwval.simulator`)."""

from __future__ import annotations

from uwval.errors import UwvalError


class SimulationError(UwvalError):
    """The simulator cannot run (bad parameters, divergence)."""


class DivergenceError(SimulationError):
    """A run diverged: its body twist left the finite range at ``at_s`` s of sim time."""

    def __init__(self, message: str, at_s: float) -> None:
        super().__init__(message)
        self.at_s = at_s

    def __reduce__(self) -> tuple[type[DivergenceError], tuple[str, float]]:
        # rebuilt with both arguments when it crosses a process boundary (physics workers)
        return (DivergenceError, (str(self), self.at_s))
