"""The compare engine: two pose streams in, aligned samples, per-axis errors and statistics out.

Pipeline (DESIGN.md sections 3 and 7, issues 3 and 31): clock drift (``drift='auto'``: fitted
and removed from the other stream's stamps) -> frame conversion of both streams into the
canonical ENU/FLU convention (``frame='auto'`` asks the frame doctor) -> clock offset (given,
or estimated from applied stamps or the motion, refused when the motion cannot pin it) ->
time association (``interp``: lerp/slerp of the other stream at the reference stamps, never
extrapolated, gaps masked; ``nearest``: evo's association) -> optional spatial alignment
(evo's Umeyama / origin) -> signed errors other - reference per axis, position-error norm,
geodesic angle -> statistics, the lag fitted from the poses (:mod:`uwval.comparison.lag`)
and the JSON contract.

:func:`compare` reads its options into a :class:`CompareSettings`; each step is a function
of its own (:func:`_settle_clock`, :func:`_associate_interp` / :func:`_associate_nearest`,
:func:`_spatial_alignment`, :func:`_lag_fit`) passing small frozen dataclasses
(:class:`ClockSetting`, :class:`AlignedSamples`); the numerics live in sync, align, offset,
stats and lag.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from uwval.comparison.align import Alignment, AlignMode, estimate_alignment
from uwval.comparison.doctor import FrameDiagnosis, diagnose, thinning_step
from uwval.comparison.lag import MAX_FIT_SAMPLES, LagFit, fit_lag
from uwval.comparison.offset import (
    DriftFit,
    OffsetEstimate,
    drift_from_applied_stamps,
    drift_from_motion,
    estimate_offset,
    latency_stats,
    remove_drift,
)
from uwval.comparison.relations import RELATION_UNITS
from uwval.comparison.stats import axis_stats, norm_stats
from uwval.comparison.sync import (
    associate_nearest,
    index_or_slice,
    interpolate_at,
    nominal_period_ns,
)
from uwval.compat import StrEnum
from uwval.errors import AlignmentError, PoseStreamError, UwvalError
from uwval.frames import CONVENTIONS, convert_stream, get_convention
from uwval.posestream import MAX_ABS_STAMP_S, PoseStream
from uwval.rotations import (
    Scratch,
    geodesic_angle,
    geodesic_deg,
    geodesic_deg_into,
    rpy_from_quat,
)

F64 = NDArray[np.float64]
I64 = NDArray[np.int64]

AXES = ("x", "y", "z", "roll", "pitch", "yaw")


class SyncMethod(StrEnum):
    """Time association methods (a StrEnum: each equals its CLI string)."""

    INTERP = "interp"
    NEAREST = "nearest"


SYNC_METHODS = tuple(m.value for m in SyncMethod)
JSON_SCHEMA_VERSION = 1

#: Largest offset, gap or time difference accepted (s): beyond it stamps leave int64 ns.
MAX_SECONDS = MAX_ABS_STAMP_S

#: Largest |position| coordinate accepted (m): far beyond any vehicle (Earth-centred
#: coordinates are ~6.4e6 m), small enough that squared errors of 1e6 samples stay finite.
MAX_POSITION_M = 1e9


@dataclass
class ComparisonResult:
    """Everything one comparison found.

    Attributes:
        t: (M,) int64 aligned stamps (ns, reference clock): the reference stamps for
            ``interp``; the driving (shorter) stream's stamps for ``nearest``, as evo.
        reference, other: aligned PoseStreams on ``t``, both ENU world / FLU body; ``other``
            has the offset, frame conversion and spatial alignment applied. Where no copy is
            needed (rows that are one run, an ENU input) their arrays are views of the input
            streams' arrays: treat them as read-only, as the inputs.
        errors: signed per-axis errors other - reference: x y z (m), roll pitch yaw (deg,
            wrapped to (-180, 180]); plus ``position_norm`` (m) and ``rotation_angle`` (deg).
        stats: the JSON-ready statistics (see :meth:`to_json`).
    """

    t: I64
    reference: PoseStream
    other: PoseStream
    stats: dict[str, Any]
    alignment: Alignment
    offset_s: float
    offset_estimate: OffsetEstimate | None = None
    diagnosis: FrameDiagnosis | None = None
    warnings: list[str] = field(default_factory=list)
    lag: LagFit | None = None

    _errors: dict[str, F64] | None = field(default=None, repr=False)

    @property
    def n_samples(self) -> int:
        return int(self.t.shape[0])

    @property
    def errors(self) -> dict[str, F64]:
        """Signed per-axis error series (computed from the aligned streams on first use, so a
        large comparison does not hold eight extra series unless someone asks for them)."""
        if self._errors is None:
            self._errors = _error_series(
                self.reference.position,
                self.reference.orientation,
                self.other.position,
                self.other.orientation,
            )
        return self._errors

    def to_json(self) -> dict[str, Any]:
        """The JSON contract of ``uwval compare --json`` (plain dicts, lists, floats, None)."""
        out: dict[str, Any] = _json_clean(self.stats)
        return out

    def to_dataframe(self) -> Any:
        """A pandas DataFrame: t (s), reference/other poses and every error series."""
        import pandas as pd

        data: dict[str, Any] = {"t": self.t.astype(np.float64) * 1e-9}
        ref_rpy = np.degrees(rpy_from_quat(self.reference.orientation))
        oth_rpy = np.degrees(rpy_from_quat(self.other.orientation))
        for j, ax in enumerate("xyz"):
            data[f"ref_{ax}"] = self.reference.position[:, j]
            data[f"other_{ax}"] = self.other.position[:, j]
        for j, ax in enumerate(("roll", "pitch", "yaw")):
            data[f"ref_{ax}"] = ref_rpy[:, j]
            data[f"other_{ax}"] = oth_rpy[:, j]
        for name, series in self.errors.items():
            data[f"err_{name}"] = series
        return pd.DataFrame(data)


#: evo's APE pose relations (``evo_ape -r``) and the unit of each error: RPE's, without the
#: one that needs a travelled distance.
APE_RELATIONS = {r: u for r, u in RELATION_UNITS.items() if r != "point_distance_error_ratio"}


def ape_errors(reference: PoseStream, other: PoseStream, relation: str) -> F64:
    """Absolute pose error per aligned sample under evo's pose ``relation`` (``evo_ape -r``).

    With E = Q^-1 P (Q the reference pose, P the other, both ENU world / FLU body on the same
    stamps): ``trans_part`` and ``point_distance`` |p - q| (m); ``angle_rad`` / ``angle_deg``
    the rotation angle of R_E; ``rot_part`` |R_E - I|_F = 2 sqrt(2) |sin(angle / 2)|
    (unitless); ``full`` |E - I|_F = sqrt(rot_part^2 + |p - q|^2) (as evo's 4x4 matrices).
    Vectorized over samples, no 4x4 matrices.
    """
    if relation not in APE_RELATIONS:
        raise AlignmentError(
            f"--pose_relation {relation!r}: choose one of {', '.join(APE_RELATIONS)}"
        )
    if relation in ("trans_part", "point_distance"):
        return _position_norm(reference.position, other.position)
    angle = geodesic_angle(other.orientation, reference.orientation)
    if relation == "angle_rad":
        return angle
    if relation == "angle_deg":
        return np.degrees(angle)
    rot = 2.0 * math.sqrt(2.0) * np.abs(np.sin(angle / 2.0))
    if relation == "rot_part":
        return rot
    trans = _position_norm(reference.position, other.position)
    return np.sqrt(rot * rot + trans * trans)


def ape_statistics(reference: PoseStream, other: PoseStream, relation: str) -> dict[str, Any]:
    """evo_ape's statistics (rmse, mean, median, std, min, max, sse) of :func:`ape_errors`."""
    stats: dict[str, Any] = {"pose_relation": relation, "unit": APE_RELATIONS.get(relation, "")}
    stats.update(norm_stats(ape_errors(reference, other, relation)))
    return stats


def _names_convention(frame_id: str) -> bool:
    """Whether a frame_id is a uwval convention name or alias (it states axes, not origin)."""
    try:
        get_convention(frame_id)
    except UwvalError:  # FrameError: not a convention name
        return False
    return True


def frame_id_mismatch(reference: PoseStream, other: PoseStream) -> str:
    """A warning when the two streams' header frame_ids (read from the log) differ, e.g.
    ``/odom`` (frame_id ``odom``) vs ``/amcl_pose`` (``map``); "" when they agree or are
    unknown. frame_ids that name a uwval convention (``unity-flu``, ``enu``...) state the
    axes, not the origin, and are left out."""
    a = [f for f in reference.frame_ids if f and not _names_convention(f)]
    b = [f for f in other.frame_ids if f and not _names_convention(f)]
    if not a or not b or set(a) == set(b):
        return ""
    return (
        f"the streams are in different frames: {reference.describe()} has frame_id "
        f"{', '.join(map(repr, a))}, {other.describe()} has {', '.join(map(repr, b))}; "
        "their poses differ by the transform between the frames (compare topics in one "
        "frame, or fit it with --align se3)"
    )


def _json_clean(obj: Any) -> Any:
    """NaN/inf -> None (JSON has no NaN), numpy scalars -> Python numbers."""
    if isinstance(obj, dict):
        return {str(k): _json_clean(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_json_clean(v) for v in obj]
    if isinstance(obj, np.generic):
        obj = obj.item()
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    return obj


def _stream_info(s: PoseStream) -> dict[str, Any]:
    return {
        "topic": s.topic,
        "source": s.source,
        "frame": s.frame,
        "n": len(s),
        "start_s": float(s.t[0]) * 1e-9 if len(s) else None,
        "duration_s": s.duration,
        "repairs": dict(s.repairs),
        "dropped": dict(s.dropped),
        "warnings": list(s.warnings),
    }


def _time_range(s: PoseStream, shift_s: float = 0.0) -> str:
    """``[first, last] s`` of a stream's stamps (plus ``shift_s``), for messages."""
    if not len(s):
        return "no samples"
    return f"[{s.t[0] * 1e-9 + shift_s:.3f}, {s.t[-1] * 1e-9 + shift_s:.3f}] s"


def _overlap_hint(reference: PoseStream, other: PoseStream, offset_s: float) -> str:
    """Why two streams gave no aligned samples: their time ranges, and what to do about it."""
    ref, oth = _time_range(reference), _time_range(other, offset_s)
    apart = (
        len(reference)
        and len(other)
        and (
            other.t[0] * 1e-9 + offset_s > reference.t[-1] * 1e-9
            or other.t[-1] * 1e-9 + offset_s < reference.t[0] * 1e-9
        )
    )
    if apart:
        return (
            f"the streams do not overlap in time (reference {ref}, other {oth} after the "
            "offset): their clocks differ? --offset auto estimates the offset from the "
            "motion, --offset S gives a known one"
        )
    return f"reference {ref}, other {oth} after the offset: too few samples match in time"


def _to_canonical(stream: PoseStream) -> PoseStream:
    return convert_stream(stream, "enu")


def _offset_ns(offset_s: float) -> int:
    return round(offset_s * 1e9)


class DriftMode(StrEnum):
    """Clock drift handling (a StrEnum: each equals its CLI string)."""

    OFF = "off"
    AUTO = "auto"


DRIFT_MODES = tuple(m.value for m in DriftMode)

#: A run at least this long (s) whose clocks drift apart by at least DRIFT_WARN_PPM, and by at
#: least DRIFT_WARN_MS over the run, gets a warning when the drift is not removed.
DRIFT_WARN_MIN_S = 60.0
DRIFT_WARN_PPM = 5.0
DRIFT_WARN_MS = 1.0


@dataclass(frozen=True)
class CompareSettings:
    """How :func:`compare` lines the streams up and what it computes (its doc says each)."""

    frame: str | None = None
    sync: SyncMethod | str = SyncMethod.INTERP
    max_gap: float | None = None
    max_diff: float = 0.01
    offset: float | str = 0.0
    max_offset: float | None = None
    align: AlignMode | str = AlignMode.NONE
    min_samples: int = 2
    check_frame: bool | None = None
    n_to_align: int = -1
    drift: DriftMode | str = DriftMode.OFF
    lag: bool = True
    lag_seed: int = 0


@dataclass(frozen=True)
class AlignedSamples:
    """The two streams' poses on common stamps (ENU world / FLU body, reference clock).

    ``t`` int64 ns; positions (M, 3) m; orientations (M, 4) xyzw; ``sync_info`` the JSON
    ``sync`` section (what matched, what was masked or dropped)."""

    t: I64
    ref_pos: F64
    ref_quat: F64
    oth_pos: F64
    oth_quat: F64
    sync_info: dict[str, Any]


@dataclass(frozen=True)
class ClockSetting:
    """The frame and clock offset compare settled on for the other stream."""

    configured: str
    raw_other: PoseStream
    offset_s: float
    estimate: OffsetEstimate | None
    diagnosis: FrameDiagnosis | None
    period_ns: int


def compare(
    reference: PoseStream,
    other: PoseStream,
    settings: CompareSettings | None = None,
    **options: Any,
) -> ComparisonResult:
    """Compare ``other`` (e.g. Unity) against ``reference`` (Gazebo, the truth).

    ``options`` are fields of :class:`CompareSettings` (they override ``settings``):

    - ``frame``: the other stream's convention (default: ``other.frame``, read from the log);
      ``"auto"`` lets the frame doctor pick it.
    - ``sync``: ``"interp"`` (lerp + slerp of other at the reference stamps, no
      extrapolation, samples in gaps longer than ``max_gap`` seconds masked; default 5
      nominal periods) or ``"nearest"`` (evo's association within ``max_diff`` seconds).
    - ``offset``: seconds added to the other stream's stamps (evo's ``offset_2`` sign), or
      ``"auto"`` to estimate it (applied stamps, else the motion; bounded by
      ``max_offset``); refused when the motion cannot pin it (constant velocity, no
      excitation), a warning when it repeats.
    - ``drift``: ``"auto"`` fits the other clock's rate error (ppm; applied stamps, else the
      lag's trend over the run) and removes it before the offset; ``"off"`` (default) leaves
      it and warns when a long run shows one.
    - ``align``: ``none``, ``se3``, ``sim3`` (Umeyama, as evo), ``origin``, or ``scale``
      (evo's ``-s`` alone); ``n_to_align``: fit it on the first samples only (-1: all).
    - ``min_samples``: fewer aligned samples than this is an :class:`AlignmentError`.
    - ``check_frame``: run the frame doctor and warn when another convention fits better;
      default: when the other stream is in a Unity (left-handed) convention.
    - ``lag``: fit the lag from the poses (:mod:`uwval.comparison.lag`), seeded by
      ``lag_seed``; its JSON section is ``lag``.
    """
    s = settings or CompareSettings()
    if options:
        unknown = sorted(set(options) - set(CompareSettings.__dataclass_fields__))
        if unknown:
            raise TypeError(f"compare() got unexpected keyword argument(s) {unknown}")
        s = replace(s, **options)
    s = _checked_settings(s)
    _check_streams(reference, other)
    drift: DriftFit | None = None
    if s.drift == "auto":
        drift = _fit_drift(reference, other, s)
        other = remove_drift(other, drift.removed_ppm)
    return _compare_once(reference, other, s, drift)


def _checked_settings(s: CompareSettings) -> CompareSettings:
    """The settings with their enums as plain strings, or an AlignmentError naming what is
    wrong."""
    if s.sync not in SYNC_METHODS:
        raise AlignmentError(
            f"unknown sync method {s.sync!r}; choose one of {', '.join(SYNC_METHODS)}"
        )
    if s.drift not in DRIFT_MODES:
        raise AlignmentError(
            f"unknown drift mode {s.drift!r}; choose one of {', '.join(DRIFT_MODES)}"
        )
    if s.max_gap is not None and not (s.max_gap > 0 and s.max_gap <= MAX_SECONDS):
        raise AlignmentError(
            f"max_gap must be a positive number of seconds up to {MAX_SECONDS:.4g}, got {s.max_gap}"
        )
    if not (s.max_diff >= 0 and s.max_diff <= MAX_SECONDS):
        raise AlignmentError(
            f"max_diff must be a non-negative number of seconds up to {MAX_SECONDS:.4g}, "
            f"got {s.max_diff}"
        )
    offset = s.offset
    if isinstance(offset, str) and offset != "auto":
        try:
            offset = float(offset)
        except ValueError:
            raise AlignmentError(f"offset must be seconds or 'auto', got {offset!r}") from None
    if isinstance(offset, int | float):
        _check_offset(offset)
        offset = float(offset)
    if s.max_offset is not None and not s.max_offset > 0:  # NaN fails too
        raise AlignmentError(
            f"max_offset must be a positive number of seconds (or none), got {s.max_offset}"
        )
    # plain strs from here on (they go into the JSON)
    return replace(s, sync=SyncMethod(s.sync).value, drift=DriftMode(s.drift).value, offset=offset)


def _check_streams(reference: PoseStream, other: PoseStream) -> None:
    if len(reference) < 1 or len(other) < 1:
        raise AlignmentError("cannot compare an empty stream")
    for stream in (reference, other):
        check_pose_values(stream)


def _input_warnings(reference: PoseStream, other: PoseStream) -> list[str]:
    """What the readers found wrong with either source (it travels with the result: never
    silent), messages not used, and a frame_id mismatch."""
    # (dict.fromkeys: once each, in order: two topics of one log carry the same log warning)
    warnings: list[str] = list(dict.fromkeys(w for s in (reference, other) for w in s.warnings))
    for s in (reference, other):
        if s.dropped:
            causes = ", ".join(f"{n} {cause}" for cause, n in sorted(s.dropped.items()))
            warnings.append(
                f"{s.describe()}: {sum(s.dropped.values())} message(s) not used ({causes})"
            )
    mismatch = frame_id_mismatch(reference, other)
    if mismatch:
        warnings.append(mismatch)
    return warnings


def _settle_clock(
    ref_c: PoseStream, other: PoseStream, s: CompareSettings, warnings: list[str]
) -> ClockSetting:
    """The other stream's frame (given, from the log, or the doctor's) and clock offset
    (given or estimated; redone after a frame change: the velocity match depends on it)."""
    frame = s.frame
    configured = other.frame if frame in (None, "auto") else get_convention(frame).name
    raw_other = other.with_(frame=configured) if configured != other.frame else other
    estimate: OffsetEstimate | None = None
    if s.offset == "auto":
        if frame == "auto":
            # the frame is unknown yet: estimate under every known convention, keep the
            # one whose velocities agree best (the doctor then confirms the frame)
            trials = [
                estimate_offset(
                    ref_c, _to_canonical(other.with_(frame=name)), max_offset=s.max_offset
                )
                for name in CONVENTIONS
            ]
            estimate = max(trials, key=lambda e: e.correlation)
        else:
            estimate = estimate_offset(ref_c, _to_canonical(raw_other), max_offset=s.max_offset)
        offset_s = estimate.offset
    else:
        offset_s = float(s.offset)
    # the other stream's nominal period (its stamps' median step; frame and offset do not
    # change it): the default gap limit of both interpolations and a sync_info entry
    period_ns = nominal_period_ns(other.t)
    diagnosis: FrameDiagnosis | None = None
    check_frame = s.check_frame
    if check_frame is None:
        check_frame = get_convention(configured).left_handed
    if (frame == "auto" or check_frame) and len(other) >= 2 and len(ref_c) >= 2:
        diagnosis = _diagnose(ref_c, raw_other, offset_s, configured, 5 * period_ns)
        if diagnosis is not None:
            if frame == "auto" and diagnosis.best is not None:  # adopt it; redo the offset
                configured = diagnosis.best
                raw_other = other.with_(frame=configured)
                if estimate is not None:
                    estimate = estimate_offset(
                        ref_c, _to_canonical(raw_other), max_offset=s.max_offset
                    )
                    offset_s = estimate.offset
            elif diagnosis.warning:
                warnings.append(diagnosis.warning)
    if estimate is not None and estimate.note:
        warnings.append(estimate.note)
    return ClockSetting(configured, raw_other, offset_s, estimate, diagnosis, period_ns)


def _associate_interp(
    ref_c: PoseStream,
    oth_c: PoseStream,
    s: CompareSettings,
    clock: ClockSetting,
    warnings: list[str],
) -> AlignedSamples:
    """The other stream interpolated at the reference stamps (gaps masked)."""
    sync_info: dict[str, Any] = {"method": s.sync, "n_reference": len(ref_c), "n_other": len(oth_c)}
    max_gap_ns = 5 * clock.period_ns if s.max_gap is None else round(s.max_gap * 1e9)
    interp = interpolate_at(
        oth_c, ref_c.t, max_gap_ns=max_gap_ns, offset_ns=-_offset_ns(clock.offset_s)
    )
    # valid samples are usually one run (invalid ones only outside the other's span):
    # take the rows as views then, not copies (as nearest does; streams are not mutated)
    rows = index_or_slice(np.flatnonzero(interp.valid))
    sync_info.update(
        matched=int(interp.valid.sum()),
        masked=interp.in_gap,
        dropped=interp.outside,
        max_gap_s=interp.max_gap_ns * 1e-9,
        other_nominal_period_s=clock.period_ns * 1e-9,
    )
    if interp.in_gap:
        warnings.append(
            f"{interp.in_gap} reference samples fall in gaps of the other stream "
            f"longer than {interp.max_gap_ns * 1e-9:.6g} s and were masked"
        )
    return AlignedSamples(
        ref_c.t[rows],
        ref_c.position[rows],
        ref_c.orientation[rows],
        interp.position[rows],
        interp.orientation[rows],
        sync_info,
    )


def _associate_nearest(
    ref_c: PoseStream, oth_c: PoseStream, s: CompareSettings, offset_s: float
) -> AlignedSamples:
    """evo's nearest-stamp association within ``max_diff``."""
    match = associate_nearest(ref_c, oth_c, max_diff=s.max_diff, offset=offset_s)
    ref_sel, oth_sel = index_or_slice(match.ref_idx), index_or_slice(match.other_idx)
    if match.reference_drives:
        t = ref_c.t[ref_sel]
    else:
        t = oth_c.t[oth_sel]
        if _offset_ns(offset_s):
            t = t + np.int64(_offset_ns(offset_s))
    matched = int(match.ref_idx.size)
    sync_info: dict[str, Any] = {"method": s.sync, "n_reference": len(ref_c), "n_other": len(oth_c)}
    sync_info.update(
        matched=matched,
        masked=0,
        dropped=match.n_candidates - matched,
        max_diff_s=s.max_diff,
        driving_stream="reference" if match.reference_drives else "other",
        reused_reference=_repeats(match.ref_idx),
        reused_other=_repeats(match.other_idx),
    )
    return AlignedSamples(
        t,
        ref_c.position[ref_sel],
        ref_c.orientation[ref_sel],
        oth_c.position[oth_sel],
        oth_c.orientation[oth_sel],
        sync_info,
    )


def _spatial_alignment(s: CompareSettings, a: AlignedSamples) -> Alignment:
    """The spatial alignment of the other poses onto the reference (evo's options)."""
    align, n_to_align = s.align, s.n_to_align
    if align == "scale_origin":  # evo_ape -s --align_origin: the scale, then the origin
        from uwval.comparison.rpe import _alignment

        scale = _alignment("scale", n_to_align, a.ref_pos, a.ref_quat, a.oth_pos, a.oth_quat)
        p1, q1 = scale.apply(a.oth_pos, a.oth_quat)
        origin = estimate_alignment("origin", a.ref_pos, a.ref_quat, p1, q1)
        # R (s p) + t = s R p + t: one similarity transform
        return Alignment("scale_origin", origin.rotation, origin.translation, scale.scale)
    if n_to_align == -1 and align != "scale":
        return estimate_alignment(align, a.ref_pos, a.ref_quat, a.oth_pos, a.oth_quat)
    from uwval.comparison.rpe import _alignment  # evo's -s alone / --n_to_align

    return _alignment(str(align), n_to_align, a.ref_pos, a.ref_quat, a.oth_pos, a.oth_quat)


def _compare_once(
    reference: PoseStream, other: PoseStream, s: CompareSettings, drift: DriftFit | None = None
) -> ComparisonResult:
    """One pass of the pipeline (frame, offset, association, alignment, statistics) with the
    other stream's clock as given (``drift``, if fitted, already removed from it). With
    ``drift='off'`` a long run whose clocks drift apart gets a warning."""
    warnings = _input_warnings(reference, other)
    frame_source = (
        "argument" if s.frame not in (None, "auto") else ("auto" if s.frame else "stream")
    )
    ref_c = _to_canonical(reference)
    clock = _settle_clock(ref_c, other, s, warnings)
    oth_c = _to_canonical(clock.raw_other)
    offset_s = clock.offset_s
    if s.sync == "interp":
        samples = _associate_interp(ref_c, oth_c, s, clock, warnings)
    else:
        samples = _associate_nearest(ref_c, oth_c, s, offset_s)
    t = samples.t
    n = int(t.shape[0])
    if n < max(1, s.min_samples):
        raise AlignmentError(
            f"only {n} aligned samples between {reference.describe()} and {other.describe()} "
            f"(need {s.min_samples}; offset {offset_s:g} s, sync {s.sync}): "
            + _overlap_hint(reference, other, offset_s)
        )
    alignment = _spatial_alignment(s, samples)
    oth_pos, oth_quat = alignment.apply(samples.oth_pos, samples.oth_quat)
    ref_pos, ref_quat = samples.ref_pos, samples.ref_quat
    # errors: statistics axis by axis; the series themselves are recomputed on demand
    axes, position_norm_stats, rotation_stats = _axis_statistics(
        ref_pos, ref_quat, oth_pos, oth_quat
    )
    latency = latency_stats(other, offset_s, (int(reference.t[0]), int(reference.t[-1])))
    estimate = clock.estimate
    if latency is not None and estimate is not None:
        # the motion cannot tell a clock offset from a delay: the estimate absorbs both
        latency["note"] = (
            "the offset was estimated from the motion and absorbs the mean "
            "latency; give --offset S (the known clock offset) for absolute "
            "latency"
        )
    lag = _lag_fit(samples, oth_pos, oth_quat, s, other, clock, latency) if s.lag else None
    if s.drift == "off":
        unremoved = _unremoved_drift(reference, other, t, ref_pos, oth_pos)
        if unremoved:
            warnings.append(unremoved)
    sync_info = samples.sync_info
    stats: dict[str, Any] = {
        "schema": JSON_SCHEMA_VERSION,
        "n_samples": n,
        "reference": _stream_info(reference),
        "other": _stream_info(other),
        "frame": {
            "configured": clock.configured,
            "source": frame_source,
            "reference": get_convention(reference.frame).name,
            "compared_in": "enu",
        },
        "frame_doctor": clock.diagnosis.to_json() if clock.diagnosis else None,
        "sync": sync_info,
        "counts": {k: sync_info[k] for k in ("matched", "masked", "dropped")},
        "offset": {
            "applied_s": offset_s,
            "source": "auto" if estimate else "argument",
            "estimate": estimate.to_json() if estimate else None,
            "drift_ppm": drift.removed_ppm if drift else 0.0,
            "drift": drift.to_json() if drift else None,
        },
        "latency": latency,
        "lag": lag.to_json() if lag else None,
        "alignment": alignment.to_json(),
        "axes": axes,
        "position_error_norm": position_norm_stats,
        "rotation_error_deg": rotation_stats,
        "warnings": warnings,
    }
    if s.lag and lag is None:
        stats["lag_reason"] = (
            "no lag fitted: the reference does not move enough (or fewer than 8 samples, or "
            "repeated stamps)"
        )
    aligned_ref = PoseStream(
        t=t,
        position=ref_pos,
        orientation=ref_quat,
        frame="enu",
        topic=reference.topic,
        source=reference.source,
    )
    aligned_oth = PoseStream(
        t=t,
        position=oth_pos,
        orientation=oth_quat,
        frame="enu",
        topic=other.topic,
        source=other.source,
    )
    return ComparisonResult(
        t=t,
        reference=aligned_ref,
        other=aligned_oth,
        stats=stats,
        alignment=alignment,
        offset_s=offset_s,
        offset_estimate=estimate,
        diagnosis=clock.diagnosis,
        warnings=warnings,
        lag=lag,
    )


def _lag_fit(
    samples: AlignedSamples,
    oth_pos: F64,
    oth_quat: F64,
    s: CompareSettings,
    other: PoseStream,
    clock: ClockSetting,
    latency: dict[str, Any] | None,
) -> LagFit | None:
    """The lag fitted from the aligned poses (thinned to MAX_FIT_SAMPLES), with the latency
    measured from applied stamps at the same samples when the log has them and the clock
    offset was not estimated (an estimate absorbs the latency)."""
    t = samples.t
    n = int(t.shape[0])
    step = max(1, math.ceil(n / MAX_FIT_SAMPLES))
    rows = slice(None, None, step)
    t_fit = t[rows]
    tq = (t_fit - t[0]).astype(np.float64) * 1e-9
    if tq.size < 8 or not bool(np.all(np.diff(tq) > 0)):
        return None
    ref_angles, errs, _ = _angle_errors(
        np.ascontiguousarray(samples.ref_quat[rows]), np.ascontiguousarray(oth_quat[rows])
    )
    ref_rpy = np.column_stack([_unwrap_deg(a, in_place=True) for a in ref_angles])
    age = None
    if other.applied_stamp is not None and clock.estimate is None and len(other) >= 2:
        # each frame's age (its stamp on the reference clock minus the stamp it showed),
        # lerped at the samples as the other's poses are
        frame_t = other.t + np.int64(_offset_ns(clock.offset_s))
        frame_age = (frame_t - other.applied_stamp).astype(np.float64) * 1e-9
        age = np.interp(
            (t_fit - t[0]).astype(np.float64), (frame_t - t[0]).astype(np.float64), frame_age
        )
    fit = fit_lag(
        tq,
        samples.ref_pos[rows],
        oth_pos[rows],
        ref_rpy,
        np.column_stack(errs),
        age_s=age,
        seed=s.lag_seed,
    )
    if fit is None:
        return None
    notes: list[str] = []
    if clock.estimate is not None:
        notes.append(
            "the clock offset was estimated (from the motion or applied stamps) and absorbs "
            "most of the lag: give --offset S (the known clock offset) to see the lag itself"
        )
    mean = float(latency["mean_ms"]) * 1e-3 if latency and clock.estimate is None else None
    return replace(fit, measured_mean_s=mean, notes=notes)


def _fit_drift(reference: PoseStream, other: PoseStream, s: CompareSettings) -> DriftFit:
    """The other clock's drift: from applied stamps when the log has them (on the reference
    clock), else from the trend of the lag fitted in windows of one drift-free pass."""
    from_stamps = drift_from_applied_stamps(reference, other)
    if from_stamps is not None:
        return from_stamps
    first = _compare_once(
        reference,
        other,
        replace(s, lag=False, sync="interp", align="none"),  # no drift check
    )
    fit = drift_from_motion(
        (first.t - first.t[0]).astype(np.float64) * 1e-9,
        first.reference.position,
        first.other.position,
    )
    if fit is None:
        raise AlignmentError(
            "--drift auto: the log has no applied stamps and the motion cannot pin a drift "
            "(too short or too little motion in its windows); give --drift off"
        )
    return fit


def _unremoved_drift(
    reference: PoseStream, other: PoseStream, t: I64, ref_pos: F64, oth_pos: F64
) -> str:
    """A warning when a long run (aligned stamps ``t``, positions on them) shows a clock drift
    that was not removed, else ""."""
    duration = (int(t[-1]) - int(t[0])) * 1e-9 if t.shape[0] else 0.0
    if duration < DRIFT_WARN_MIN_S:
        return ""
    fit = drift_from_applied_stamps(reference, other)
    if fit is None:
        fit = drift_from_motion((t - t[0]).astype(np.float64) * 1e-9, ref_pos, oth_pos)
    if fit is None or not fit.significant:
        return ""
    total_ms = abs(fit.ppm) * 1e-6 * duration * 1e3
    if abs(fit.ppm) < DRIFT_WARN_PPM or total_ms < DRIFT_WARN_MS:
        return ""
    return (
        f"the other clock drifts by {fit.ppm:+.1f} ppm against the reference ({fit.source}): "
        f"{total_ms:.1f} ms over the run's {duration:.0f} s, not removed; give --drift auto"
    )


def _check_offset(offset: float) -> None:
    """Refuse an offset that is not finite or would carry stamps beyond int64 nanoseconds."""
    if not (math.isfinite(offset) and abs(offset) <= MAX_SECONDS):
        raise AlignmentError(
            f"offset must be a finite number of seconds within +-{MAX_SECONDS:.4g}, got {offset}"
        )


def check_pose_values(stream: PoseStream) -> None:
    """Refuse a stream whose positions or orientations are NaN/inf or whose positions exceed
    ``MAX_POSITION_M`` (their squares would overflow the statistics into inf or null).

    PoseStream's own constructor checks shapes and stamps only; ``from_arrays`` and the log
    readers already refuse NaN, but a stream built directly may hold anything.
    """
    pos, quat = stream.position, stream.orientation
    if len(stream) == 0:
        return
    # max |p| as max(max p, -min p), and min/max of the quaternions: reductions without
    # temporaries; NaN propagates through each, inf shows in them
    big = max(float(pos.max()), -float(pos.min()))  # both NaN when one value is
    q_ok = math.isfinite(float(quat.min())) and math.isfinite(float(quat.max()))
    if not (big <= MAX_POSITION_M) or not q_ok:
        finite = np.isfinite(pos).all(axis=1) & np.isfinite(quat).all(axis=1)
        if not finite.all():
            bad = int(np.flatnonzero(~finite)[0])
            raise PoseStreamError(
                f"{stream.describe()}: sample {bad} (t={int(stream.t[bad])} ns) has a NaN or "
                f"infinite value ({int((~finite).sum())} such samples)"
            )
        bad = int(np.argmax(np.abs(pos).max(axis=1)))
        raise PoseStreamError(
            f"{stream.describe()}: position of sample {bad} (t={int(stream.t[bad])} ns) is "
            f"{float(np.abs(pos[bad]).max()):.6g} m from the origin, beyond "
            f"{MAX_POSITION_M:.0e} m: not a vehicle position (wrong units or a corrupt value?)"
        )


def _repeats(idx: I64) -> int:
    """How many matches reuse the previous pose (indices come out non-decreasing)."""
    return int(np.count_nonzero(np.diff(idx) == 0)) if idx.size > 1 else 0


#: Rows per step of the row-wise error series: a step's temporaries stay in the CPU cache
#: (the quaternion columns are strided views of the (N, 4) orientation tables).
ROW_CHUNK = 1 << 14


def _position_norm(ref_pos: F64, oth_pos: F64) -> F64:
    """|other - reference| per sample (m)."""
    out = np.empty(ref_pos.shape[0])
    for s in range(0, ref_pos.shape[0], ROW_CHUNK):
        r, o = ref_pos[s : s + ROW_CHUNK], oth_pos[s : s + ROW_CHUNK]
        d2 = np.square(o[:, 0] - r[:, 0])
        for j in (1, 2):
            d2 += np.square(o[:, j] - r[:, j])
        np.sqrt(d2, out=out[s : s + ROW_CHUNK])
    return out


def _rpy_deg_into(q: F64, out: Sequence[F64], sc: Scratch) -> None:
    """ROS roll, pitch, yaw (fixed-axis XYZ) in degrees of (k, 4) xyzw quaternions into the
    three (k,) arrays ``out``: :func:`uwval.rotations.rpy_from_quat`'s formulas, operation for
    operation (equal to the bit), with the squares shared and no temporary allocated."""
    k = q.shape[0]
    x, y, z, w = q[:, 0], q[:, 1], q[:, 2], q[:, 3]
    a, b, yy = sc.get(0, k), sc.get(1, k), sc.get(2, k)
    np.multiply(y, y, out=yy)
    # roll = atan2(2 (w x + y z), 1 - 2 (x x + y y))
    np.multiply(w, x, out=a)
    np.multiply(y, z, out=b)
    a += b
    a *= 2
    np.multiply(x, x, out=b)
    b += yy
    b *= 2
    np.subtract(1, b, out=b)
    np.arctan2(a, b, out=out[0])
    # pitch = asin(clip(2 (w y - z x), -1, 1))
    np.multiply(w, y, out=a)
    np.multiply(z, x, out=b)
    a -= b
    a *= 2
    np.clip(a, -1.0, 1.0, out=a)
    np.arcsin(a, out=out[1])
    # yaw = atan2(2 (w z + x y), 1 - 2 (y y + z z))
    np.multiply(w, z, out=a)
    np.multiply(x, y, out=b)
    a += b
    a *= 2
    np.multiply(z, z, out=b)
    np.add(yy, b, out=b)
    b *= 2
    np.subtract(1, b, out=b)
    np.arctan2(a, b, out=out[2])
    for angle in out:
        np.degrees(angle, out=angle)


def _wrap_deg_into(a: F64, tmp: F64) -> None:
    """:func:`uwval.rotations.wrap_deg` of a (k,) array in place (the same operations)."""
    np.divide(a, 360.0, out=tmp)
    np.round(tmp, out=tmp)
    tmp *= 360.0
    a -= tmp
    np.add(a, 360.0, out=a, where=a <= -180.0)
    np.subtract(a, 360.0, out=a, where=a > 180.0)


def _angle_errors(ref_quat: F64, oth_quat: F64) -> tuple[list[F64], list[F64], F64]:
    """Reference ROS angles, wrapped errors other - reference (roll, pitch, yaw; three (N,)
    arrays each, deg) and the geodesic rotation error (N,) (deg), in one pass of ROW_CHUNK
    rows (separate arrays: each can be let go as soon as its axis is done)."""
    n = ref_quat.shape[0]
    ref_angle = [np.empty(n) for _ in range(3)]
    err = [np.empty(n) for _ in range(3)]
    rot = np.empty(n)
    sc = Scratch(min(n, ROW_CHUNK))
    # each step's quaternions copied component-major once: every product below then reads
    # contiguous components instead of strided columns of the (N, 4) tables
    r_rows, o_rows = np.empty((4, min(n, ROW_CHUNK))), np.empty((4, min(n, ROW_CHUNK)))
    for s in range(0, n, ROW_CHUNK):
        e = min(n, s + ROW_CHUNK)
        np.copyto(r_rows[:, : e - s], ref_quat[s:e].T)
        np.copyto(o_rows[:, : e - s], oth_quat[s:e].T)
        rq, oq = r_rows[:, : e - s].T, o_rows[:, : e - s].T
        r, d = [a[s:e] for a in ref_angle], [a[s:e] for a in err]
        _rpy_deg_into(rq, r, sc)
        _rpy_deg_into(oq, d, sc)
        for j in range(3):
            d[j] -= r[j]
            _wrap_deg_into(d[j], sc.get(0, e - s))
        geodesic_deg_into(oq, rq, rot[s:e], sc)
    return ref_angle, err, rot


def _rotation_error_deg(ref_quat: F64, oth_quat: F64) -> F64:
    """Geodesic angle of the rotation from reference to other per sample (deg)."""
    return geodesic_deg(oth_quat, ref_quat, chunk=ROW_CHUNK)


def _error_series(ref_pos: F64, ref_quat: F64, oth_pos: F64, oth_quat: F64) -> dict[str, F64]:
    """All signed error series: x y z (m), roll pitch yaw (deg, wrapped), norms."""
    errors: dict[str, F64] = {}
    for j, ax in enumerate("xyz"):
        errors[ax] = oth_pos[:, j] - ref_pos[:, j]
    _, err, rot = _angle_errors(ref_quat, oth_quat)
    for j, ax in enumerate(("roll", "pitch", "yaw")):
        errors[ax] = err[j]
    errors["position_norm"] = _position_norm(ref_pos, oth_pos)
    errors["rotation_angle"] = rot
    return errors


def _axis_statistics(
    ref_pos: F64, ref_quat: F64, oth_pos: F64, oth_quat: F64
) -> tuple[dict[str, Any], dict[str, float], dict[str, float]]:
    """Per-axis statistics, position-norm and rotation-angle statistics."""
    axes: dict[str, Any] = {}
    for j, ax in enumerate("xyz"):
        # contiguous copies of the columns: faster reductions; the other's copy is scratch
        ref_j, oth_j = ref_pos[:, j].copy(), oth_pos[:, j].copy()
        err = oth_j - ref_j
        axes[ax] = axis_stats(err, ref_j, oth_j, overwrite_other=True) | {"unit": "m"}
        del err, ref_j, oth_j
    ref_angle, errs, rot = _angle_errors(ref_quat, oth_quat)
    rotation = norm_stats(rot)
    del rot
    for j, ax in enumerate(("roll", "pitch", "yaw")):
        err = errs[j]
        # correlate continuous series: unwrap the reference, other = reference + wrapped error,
        # so a 179 -> -179 deg crossing is not a 358 deg jump in either series
        ref_series = _unwrap_deg(ref_angle[j], in_place=True)
        axes[ax] = axis_stats(err, ref_series, ref_series + err, overwrite_other=True) | {
            "unit": "deg"
        }
        del ref_series, err
        ref_angle[j] = errs[j] = np.empty(0)  # this axis's series are let go
    position = norm_stats(_position_norm(ref_pos, oth_pos))
    return axes, position, rotation


def _unwrap_deg(a: F64, *, in_place: bool = False) -> F64:
    """np.unwrap(a, period=360) for degrees, with fewer temporaries (one besides the result);
    ``in_place``: ``a`` itself becomes the result."""
    if a.size < 2:
        return a if in_place else a.copy()
    jumps = np.diff(a)
    jumps /= 360.0
    np.round(jumps, out=jumps)
    jumps *= -360.0
    out = a if in_place else a.copy()
    out[1:] += np.cumsum(jumps, out=jumps)
    return out


def _diagnose(
    ref_c: PoseStream,
    raw_other: PoseStream,
    offset_s: float,
    configured: str,
    max_gap_ns: int | None = None,
) -> FrameDiagnosis | None:
    """Run the frame doctor on up to :data:`~uwval.comparison.doctor.DOCTOR_SAMPLES`
    reference stamps (evenly thinned), the other stream interpolated at them."""
    step = thinning_step(len(ref_c))
    sub = ref_c.slice(slice(None, None, step))
    interp = interpolate_at(
        raw_other, sub.t, max_gap_ns=max_gap_ns, offset_ns=-_offset_ns(offset_s)
    )
    ok = interp.valid
    if int(ok.sum()) < 3:
        return None
    return diagnose(
        sub.position[ok],
        sub.orientation[ok],
        interp.position[ok],
        interp.orientation[ok],
        configured,
    )
