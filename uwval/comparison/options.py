"""Typed options of a comparison: what ``uwval compare`` and ``uwval rpe`` hand the library.

Each command builds one frozen options object (:class:`CompareOptions`, :class:`RpeOptions`)
from its command line and the project file, and calls one library function
(:func:`uwval.comparison.logs.run_comparison`, :func:`uwval.comparison.logs.run_rpe`).
Values that are one of a set are enums whose members equal their command-line spelling.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from uwval.comparison.engine import SyncMethod
from uwval.compat import StrEnum
from uwval.errors import ConfigError

__all__ = [
    "AlignmentMode",
    "ApeUnit",
    "ClockOffset",
    "CompareInputs",
    "CompareOptions",
    "DriftMode",
    "InputFormat",
    "PoseRelation",
    "RpeOptions",
    "SyncMethod",
    "TimeWindow",
]


class AlignmentMode(StrEnum):
    """Spatial alignment of the other stream (evo's flags in brackets).

    ``se3`` (-a), ``sim3`` (-as), ``scale`` (-s alone: the scale only), ``origin``
    (--align_origin), ``scale_origin`` (-s --align_origin).
    """

    NONE = "none"
    SE3 = "se3"
    SIM3 = "sim3"
    ORIGIN = "origin"
    SCALE = "scale"
    SCALE_ORIGIN = "scale_origin"


class DriftMode(StrEnum):
    """Clock drift of the other stream: ``auto`` fits (ppm) and removes it, ``off`` leaves it."""

    AUTO = "auto"
    OFF = "off"


class PoseRelation(StrEnum):
    """evo's pose relations (``-r``); ``point_distance_error_ratio`` is RPE's only."""

    TRANS_PART = "trans_part"
    ROT_PART = "rot_part"
    FULL = "full"
    ANGLE_DEG = "angle_deg"
    ANGLE_RAD = "angle_rad"
    POINT_DISTANCE = "point_distance"
    POINT_DISTANCE_ERROR_RATIO = "point_distance_error_ratio"


class InputFormat(StrEnum):
    """Input formats of ``--format`` (and of evo's first positional word)."""

    TUM = "tum"
    KITTI = "kitti"
    EUROC = "euroc"
    MCAP = "mcap"
    BAG = "bag"
    ROSBAG2 = "rosbag2"
    DB3 = "db3"
    CSV = "csv"


#: Formats of trajectory text files as evo reads them: compared with evo's association.
TRAJECTORY_FORMATS = frozenset({InputFormat.TUM, InputFormat.KITTI, InputFormat.EUROC})


class ApeUnit(StrEnum):
    """evo's ``--change_unit`` choices: the unit the APE statistics are printed in."""

    DEG = "deg"
    RAD = "rad"
    MM = "mm"
    CM = "cm"
    M = "m"
    KM = "km"


#: Size of each unit in its base unit (metres, radians), as evo's ``Unit`` conversion.
_UNIT_SCALE = {
    ApeUnit.MM: ("m", 1e-3),
    ApeUnit.CM: ("m", 1e-2),
    ApeUnit.M: ("m", 1.0),
    ApeUnit.KM: ("m", 1e3),
    ApeUnit.DEG: ("rad", math.pi / 180.0),
    ApeUnit.RAD: ("rad", 1.0),
}


def unit_factor(from_unit: str, to_unit: ApeUnit) -> float:
    """The factor that turns a value in ``from_unit`` (an APE relation's unit) into
    ``to_unit``; a ConfigError when the two measure different things (as evo refuses)."""
    source = (
        _UNIT_SCALE.get(ApeUnit(from_unit)) if from_unit in ApeUnit._value2member_map_ else None
    )
    kind, scale = _UNIT_SCALE[to_unit]
    if source is None or source[0] != kind:
        raise ConfigError(
            f"--change_unit {to_unit}: the APE is in {from_unit or 'no unit'}, which cannot be "
            f"given in {to_unit} (as evo_ape refuses it)"
        )
    return source[1] / scale


@dataclass(frozen=True)
class ClockOffset:
    """The clock offset added to the other stream's stamps: ``seconds``, or estimated."""

    seconds: float = 0.0
    auto: bool = False

    @classmethod
    def parse(cls, text: str | float, flag: str = "--offset") -> ClockOffset:
        """``"auto"`` or a finite number of seconds (a one-line ConfigError otherwise)."""
        if isinstance(text, str) and text.strip().lower() == "auto":
            return cls(auto=True)
        try:
            seconds = float(text)
        except ValueError:
            raise ConfigError(f"{flag} must be seconds or 'auto', got {text!r}") from None
        if not math.isfinite(seconds):
            raise ConfigError(f"{flag} must be a finite number of seconds or 'auto', got {text!r}")
        return cls(seconds)

    def engine_value(self) -> float | str:
        """The value :func:`uwval.comparison.compare` takes: seconds or ``"auto"``."""
        return "auto" if self.auto else self.seconds


@dataclass(frozen=True)
class TimeWindow:
    """evo's preprocessing before the association: ``--t_start``/``--t_end`` (s, the
    reference's absolute stamps; evo trims the reference only) and ``--downsample N``
    (both streams to at most N evenly spaced poses, as evo's ``downsample``)."""

    t_start: float | None = None
    t_end: float | None = None
    downsample: int | None = None

    def __post_init__(self) -> None:
        if self.downsample is not None and self.downsample < 1:
            raise ConfigError(f"--downsample must be >= 1, got {self.downsample}")
        if self.t_start is not None and self.t_end is not None and self.t_start > self.t_end:
            raise ConfigError(
                f"--t_start {self.t_start} is after --t_end {self.t_end} (as evo refuses it)"
            )

    @property
    def active(self) -> bool:
        return self.t_start is not None or self.t_end is not None or self.downsample is not None


@dataclass(frozen=True)
class CompareInputs:
    """What is compared: one log (two topics of it), or one stream from each of two files.

    ``gazebo_topic`` is the reference, ``unity_topic`` the other stream (``TOPIC#CHILD`` for
    a TF child frame); ``pairs`` are a project file's topic pairs (uwval.config.TopicPair).
    """

    log_a: Path
    log_b: Path | None = None
    gazebo_topic: str | None = None
    unity_topic: str | None = None
    fmt: InputFormat | None = None
    pairs: tuple[Any, ...] = ()

    @property
    def trajectory_files(self) -> bool:
        """Two trajectory text files (TUM, KITTI, EuRoC) as evo reads them."""
        from uwval.io.formats import is_tum

        if self.log_b is None:
            return False
        if self.fmt is not None:
            return self.fmt in TRAJECTORY_FORMATS
        return is_tum(self.log_a) and is_tum(self.log_b)


@dataclass(frozen=True)
class CompareOptions:
    """Everything one ``uwval compare`` needs, typed.

    ``sync`` None means the default of the inputs: evo's nearest-stamp association (within
    ``max_diff`` s) for trajectory files, interpolation for logs. ``offset`` None means 0,
    and lets a log's recorded clock relation supply it (``uwval.clock`` metadata). ``frame``
    is the other stream's convention (None: from the log; ``"auto"``: the frame doctor).
    ``drift`` None leaves the engine's default (off).
    ``pose_relation`` adds evo_ape's statistics of that relation (``change_unit``: in that
    unit). ``check_frame`` forces the frame doctor (``uwval doctor``).
    """

    inputs: CompareInputs
    frame: str | None = None
    sync: SyncMethod | None = None
    max_gap: float | None = None
    max_diff: float = 0.01
    offset: ClockOffset | None = None
    max_offset: float | None = None
    drift: DriftMode | None = None
    align: AlignmentMode = AlignmentMode.NONE
    n_to_align: int = -1
    pose_relation: PoseRelation | None = None
    change_unit: ApeUnit | None = None
    window: TimeWindow = field(default_factory=TimeWindow)
    check_frame: bool | None = None

    def __post_init__(self) -> None:
        if self.n_to_align != -1 and self.n_to_align < 1:
            raise ConfigError(f"--n_to_align must be >= 1 (or -1 for all), got {self.n_to_align}")
        if self.pose_relation is PoseRelation.POINT_DISTANCE_ERROR_RATIO:
            raise ConfigError(
                "--pose_relation point_distance_error_ratio is an RPE relation: use `uwval rpe`"
            )

    @property
    def sync_method(self) -> SyncMethod:
        """The association used: as given, else evo's nearest for trajectory files."""
        if self.sync is not None:
            return self.sync
        return SyncMethod.NEAREST if self.inputs.trajectory_files else SyncMethod.INTERP

    @property
    def ape_relation(self) -> PoseRelation | None:
        """The APE relation reported: as given, or evo's default when a unit is asked for."""
        if self.pose_relation is None and self.change_unit is not None:
            return PoseRelation.TRANS_PART
        return self.pose_relation

    def engine_options(self) -> dict[str, Any]:
        """Keywords of :func:`uwval.comparison.compare` (the array-level engine)."""
        out: dict[str, Any] = {
            "sync": self.sync_method.value,
            "max_gap": self.max_gap,
            "max_diff": self.max_diff,
            "max_offset": self.max_offset,
            "align": self.align.value,
            "n_to_align": self.n_to_align,
        }
        if self.offset is not None:
            out["offset"] = self.offset.engine_value()
        if self.check_frame is not None:
            out["check_frame"] = self.check_frame
        if self.drift is not None:
            out["drift"] = self.drift.value
        return out

    def with_(self, **changes: Any) -> CompareOptions:
        """A copy with some fields changed."""
        return replace(self, **changes)


@dataclass(frozen=True)
class RpeOptions:
    """Everything one ``uwval rpe`` needs, typed (evo_rpe's options and meanings)."""

    inputs: CompareInputs
    frame: str | None = None
    relation: PoseRelation = PoseRelation.TRANS_PART
    delta: float = 1.0
    delta_unit: str = "f"
    delta_tol: float = 0.1
    all_pairs: bool = False
    pairs_from_reference: bool = False
    align: AlignmentMode = AlignmentMode.NONE
    n_to_align: int = -1
    max_diff: float = 0.01
    offset: float = 0.0
    window: TimeWindow = field(default_factory=TimeWindow)

    def __post_init__(self) -> None:
        if self.delta_unit not in ("f", "m", "d", "r"):
            raise ConfigError(
                f"--delta_unit {self.delta_unit!r}: choose f (frames), m, d (deg) or r (rad)"
            )
        if self.align is AlignmentMode.SCALE_ORIGIN:
            raise ConfigError("--align_origin cannot be combined with -s (as in evo_rpe)")


def parse_offset(text: str, flag: str = "--offset") -> float | str:
    """A command line's clock offset as the engine takes it: seconds, or ``"auto"``."""
    return ClockOffset.parse(text, flag).engine_value()
