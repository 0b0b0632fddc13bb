"""Error classes, one per area (as rosbags does), all deriving from :class:`UwvalError`.

The parts outside the core keep their own: :class:`uwval.simulator.errors.SimulationError`,
:class:`uwval.bridge.errors.BridgeError`.

The CLI catches :class:`UwvalError` and prints its message without a traceback, so every
message must name what was wrong and where (file, topic, line or byte offset).
"""

from __future__ import annotations


class UwvalError(Exception):
    """Base class of every error uwval raises on purpose."""


class PoseStreamError(UwvalError, ValueError):
    """A pose stream's arrays are invalid (shape, NaN, non-unit quaternion, empty...)."""


class FrameError(UwvalError, ValueError):
    """Unknown or invalid frame convention."""


class LogReadError(UwvalError):
    """A log file cannot be read, or lacks the requested topic."""


class LogWriteError(UwvalError):
    """A log file cannot be written."""


class AlignmentError(UwvalError):
    """Two streams cannot be aligned (no overlap, too few samples...)."""


class ConfigError(UwvalError, ValueError):
    """An experiment, vehicle, threshold or mapping file is invalid."""
