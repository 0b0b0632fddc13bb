"""PoseStream: the one columnar pose type that every stage of uwval passes on.

Times are int64 nanoseconds, positions N x 3 float64 metres, orientations N x 4 float64
unit quaternions in (x, y, z, w) order. The frame convention (see :mod:`uwval.frames`) is
carried as metadata; the arrays are never lists of 4x4 matrices.
"""

from __future__ import annotations

import math
import weakref
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from uwval.errors import PoseStreamError

#: Quaternions whose norm differs from 1 by more than this are rejected, not normalised.
QUAT_NORM_TOLERANCE = 1e-2

#: Largest |stamp| accepted, in ns (2**62 - 1 ns, about 146 years either side of 1970): any two
#: stamps then differ by less than 2**63, so differences and offsets never wrap in int64.
MAX_ABS_STAMP_NS = (1 << 62) - 1

#: Largest |stamp| accepted for float seconds (the same bound, in seconds).
MAX_ABS_STAMP_S = MAX_ABS_STAMP_NS * 1e-9

F64 = NDArray[np.float64]
I64 = NDArray[np.int64]


@dataclass(frozen=True, eq=False)
class PoseStream:
    """A time series of 6-DOF poses of one body on one topic.

    Attributes:
        t: (N,) int64 stamps in nanoseconds, strictly increasing.
        position: (N, 3) float64 positions in metres, in the world axes of ``frame``.
        orientation: (N, 4) float64 unit quaternions (x, y, z, w), body-to-world, in ``frame``.
        frame: name of the pose convention (``uwval.frames``), e.g. ``"enu"`` or ``"unity-flu"``.
        topic: topic (or column set) the poses came from.
        source: file the poses came from, if any.
        applied_stamp: (N,) int64 header stamps (ns) of the Gazebo pose each Unity sample
            showed, when the Unity side logged them; otherwise ``None``.
        repairs: counts of repairs made while validating (``sorted``, ``duplicates_dropped``,
            ``renormalized``), so that no repair is silent.
        dropped: counts, by cause (e.g. ``decode_error``, ``truncated``), of messages on the
            topic that the reader found but could not turn into samples; filled by the log
            readers, so that no lost message is silent.
        warnings: what the reader wants the user to know about the source (e.g. a log that was
            not closed cleanly, bytes that could not be recovered); travels into results.
    """

    t: I64
    position: F64
    orientation: F64
    frame: str = "enu"
    topic: str = ""
    source: str = ""
    applied_stamp: I64 | None = None
    repairs: dict[str, int] = field(default_factory=dict)
    dropped: dict[str, int] = field(default_factory=dict)
    warnings: tuple[str, ...] = ()
    frame_ids: tuple[str, ...] = ()  # header frame_id(s) in the log (TF: the parent frame)

    def __post_init__(self) -> None:
        n = self.t.shape[0] if self.t.ndim == 1 else -1
        where = self.describe()
        if self.t.ndim != 1 or self.t.dtype != np.int64:
            raise PoseStreamError(f"{where}: t must be a 1-D int64 array of nanoseconds")
        if self.position.shape != (n, 3) or self.position.dtype != np.float64:
            raise PoseStreamError(
                f"{where}: position must be ({n}, 3) float64, got {self.position.shape}"
            )
        if self.orientation.shape != (n, 4) or self.orientation.dtype != np.float64:
            raise PoseStreamError(
                f"{where}: orientation must be ({n}, 4) float64, got {self.orientation.shape}"
            )
        if self.applied_stamp is not None and self.applied_stamp.shape != (n,):
            raise PoseStreamError(f"{where}: applied_stamp must have shape ({n},)")
        if n > 0 and not _stamps_checked(self.t):
            _check_stamp_range(self.t, where)
        if n > 1 and not _stamps_checked(self.t) and not bool(np.all(np.diff(self.t) > 0)):
            raise PoseStreamError(
                f"{where}: stamps must be strictly increasing (use PoseStream.from_arrays "
                "to sort and drop duplicates)"
            )

    # ------------------------------------------------------------------ construction
    @classmethod
    def from_arrays(
        cls,
        t: ArrayLike,
        position: ArrayLike,
        orientation: ArrayLike,
        *,
        frame: str = "enu",
        topic: str = "",
        source: str = "",
        applied_stamp: ArrayLike | None = None,
        duplicates: str = "drop",
        allow_empty: bool = False,
    ) -> PoseStream:
        """Validate and repair raw arrays into a PoseStream.

        ``t`` may be int nanoseconds or float seconds (floats are taken as seconds). Floats
        too large to be seconds (beyond ``MAX_ABS_STAMP_S``, e.g. epoch nanoseconds stored as
        floats, which have already lost precision) and stamps whose differences would
        overflow int64 are refused with a :class:`PoseStreamError`.
        Unsorted stamps are sorted (counted in ``repairs['sorted']``); samples with a duplicate
        stamp are dropped keeping the first (``duplicates='drop'``) or rejected
        (``duplicates='error'``); NaN/inf values are rejected naming the first bad row;
        quaternions within ``QUAT_NORM_TOLERANCE`` of unit norm are normalised, others rejected.
        """
        where = _describe(topic, source)
        t_arr = np.asarray(t)
        kind = t_arr.dtype.kind
        if kind == "f":
            if not np.all(np.isfinite(t_arr)):
                bad = int(np.flatnonzero(~np.isfinite(t_arr))[0])
                raise PoseStreamError(f"{where}: stamp of sample {bad} is not finite")
            if t_arr.size:
                _check_float_seconds(t_arr, where)
            t_arr = np.round(t_arr * 1e9).astype(np.int64)
        elif t_arr.dtype.kind in "iu":
            if t_arr.dtype.kind == "u" and t_arr.size and int(t_arr.max()) > MAX_ABS_STAMP_NS:
                bad = int(np.argmax(t_arr))
                raise PoseStreamError(
                    f"{where}: stamp of sample {bad} ({int(t_arr[bad])} ns) is beyond "
                    f"{MAX_ABS_STAMP_NS} ns (year ~2116): not a valid time"
                )
            t_arr = t_arr.astype(np.int64)
            if t_arr.size:
                _check_stamp_range(t_arr, where)
        else:
            raise PoseStreamError(f"{where}: stamps must be numbers, got dtype {t_arr.dtype}")
        pos = np.ascontiguousarray(position, dtype=np.float64)
        quat = np.ascontiguousarray(orientation, dtype=np.float64)
        n = t_arr.shape[0]
        if n == 0 and not allow_empty:
            raise PoseStreamError(f"{where}: no poses (N = 0)")
        if pos.shape != (n, 3):
            raise PoseStreamError(f"{where}: position must have shape ({n}, 3), got {pos.shape}")
        if quat.shape != (n, 4):
            raise PoseStreamError(
                f"{where}: orientation must have shape ({n}, 4), got {quat.shape}"
            )
        # min and max propagate NaN and show +-inf: two fast reductions per array clear the
        # usual all-finite case; the row-wise scan only runs to name a bad sample
        if n and not all(math.isfinite(float(f(a))) for a in (pos, quat) for f in (np.min, np.max)):
            finite = np.isfinite(pos).all(axis=1) & np.isfinite(quat).all(axis=1)
            bad = int(np.flatnonzero(~finite)[0])
            raise PoseStreamError(
                f"{where}: sample {bad} (t={t_arr[bad]} ns) has a NaN or infinite value "
                f"({int((~finite).sum())} such samples)"
            )
        repairs: dict[str, int] = {}
        # unit quaternions (the usual case) are cleared by a fast approximate |q| (einsum,
        # within ~1e-15 of numpy's norm): exact norms only when some row may be off by 1e-9
        approx = np.einsum("ij,ij->i", quat, quat)
        np.sqrt(approx, out=approx)
        approx -= 1.0
        if n and float(np.abs(approx, out=approx).max()) > 1e-9 - 1e-12:
            norms = quat_norms(quat)
            off = np.abs(norms - 1.0)
            if float(off.max()) > QUAT_NORM_TOLERANCE:
                bad = int(np.argmax(off))
                raise PoseStreamError(
                    f"{where}: quaternion of sample {bad} has norm {norms[bad]:.6g}, "
                    f"more than {QUAT_NORM_TOLERANCE} from 1 (is it x, y, z, w order?)"
                )
            n_renorm = int(np.count_nonzero(off > 1e-9))
            if n_renorm:
                # quat / norms[:, None] (every row), column by column: a (N, 1) broadcast
                # is slow in numpy
                unit = np.empty_like(quat)
                for j in range(4):
                    np.divide(quat[:, j], norms, out=unit[:, j])
                quat = unit
                repairs["renormalized"] = n_renorm
        del approx
        stamps = None if applied_stamp is None else np.asarray(applied_stamp, dtype=np.int64)
        if n > 1:
            d = np.diff(t_arr)
            if (d < 0).any():
                order = np.argsort(t_arr, kind="stable")
                repairs["sorted"] = int((d < 0).sum())
                t_arr, pos, quat = t_arr[order], pos[order], quat[order]
                if stamps is not None:
                    stamps = stamps[order]
                d = np.diff(t_arr)
            dup = d == 0
            if dup.any():
                if duplicates == "error":
                    i = int(np.flatnonzero(dup)[0]) + 1
                    raise PoseStreamError(
                        f"{where}: duplicate stamp t={t_arr[i]} ns at sample {i} "
                        f"({int(dup.sum())} duplicates)"
                    )
                keep = np.concatenate(([True], ~dup))
                repairs["duplicates_dropped"] = int(dup.sum())
                t_arr, pos, quat = t_arr[keep], pos[keep], quat[keep]
                if stamps is not None:
                    stamps = stamps[keep]
        if t_arr.ndim == 1 and t_arr.dtype == np.int64:
            if kind == "f" and n:
                _check_stamp_range(t_arr, where)  # rounding may reach past the bound
            # sorted, no duplicates, in range, our own copy: its checks need not run again
            _remember_checked(t_arr)
        return cls(
            t=t_arr,
            position=pos,
            orientation=quat,
            frame=frame,
            topic=topic,
            source=source,
            applied_stamp=stamps,
            repairs=repairs,
        )

    # ------------------------------------------------------------------ views
    def __len__(self) -> int:
        return int(self.t.shape[0])

    @property
    def seconds(self) -> F64:
        """Stamps as float64 seconds (relative precision is fine for logs up to ~100 days)."""
        return self.t.astype(np.float64) * 1e-9

    @property
    def duration(self) -> float:
        """Time span in seconds (0 for fewer than two samples)."""
        return float(self.t[-1] - self.t[0]) * 1e-9 if len(self) > 1 else 0.0

    def describe(self) -> str:
        """Where these poses came from, for error messages."""
        return _describe(self.topic, self.source)

    def with_(self, **changes: Any) -> PoseStream:
        """A copy with some fields replaced (shapes and stamp order checked again; use
        :meth:`from_arrays` for new raw values, which also checks NaN and unit norms)."""
        return replace(self, **changes)

    def slice(self, mask_or_index: NDArray[Any] | slice) -> PoseStream:
        """A sub-stream selected by boolean mask, index array or slice."""
        stamps = None if self.applied_stamp is None else self.applied_stamp[mask_or_index]
        return replace(
            self,
            t=self.t[mask_or_index],
            position=self.position[mask_or_index],
            orientation=self.orientation[mask_or_index],
            applied_stamp=stamps,
        )

    def shifted(self, offset_ns: int) -> PoseStream:
        """The same poses with ``offset_ns`` added to every stamp (clock-offset correction)."""
        return replace(self, t=self.t + np.int64(offset_ns))

    def to_dataframe(self) -> Any:
        """A pandas DataFrame view for reporting (t in seconds, x y z, qx qy qz qw)."""
        import pandas as pd

        data = {
            "t": self.seconds,
            "x": self.position[:, 0],
            "y": self.position[:, 1],
            "z": self.position[:, 2],
            "qx": self.orientation[:, 0],
            "qy": self.orientation[:, 1],
            "qz": self.orientation[:, 2],
            "qw": self.orientation[:, 3],
        }
        if self.applied_stamp is not None:
            data["applied_stamp"] = self.applied_stamp.astype(np.float64) * 1e-9
        return pd.DataFrame(data)


#: Stamp arrays of streams built by :meth:`PoseStream.from_arrays` (by id, with a weak
#: reference to tell a reused id): strictly increasing and in range, made read-only, so the
#: checks of ``__post_init__`` need not run again for streams derived from them
#: (``with_``, frame conversion, aligned views). A contiguous forward slice of one is too.
_CHECKED_STAMPS: dict[int, weakref.ref[I64]] = {}


def _remember_checked(t: I64) -> None:
    """Mark a stamp array ``from_arrays`` validated and owns as checked (and read-only)."""
    t.flags.writeable = False
    key = id(t)

    def forget(_ref: weakref.ref[I64]) -> None:
        _CHECKED_STAMPS.pop(key, None)

    _CHECKED_STAMPS[key] = weakref.ref(t, forget)


def _stamps_checked(t: I64) -> bool:
    """Whether ``t`` is a checked stamp array or a contiguous forward slice of one."""
    if t.flags.writeable:
        return False
    for a in (t, t.base):
        ref = _CHECKED_STAMPS.get(id(a)) if a is not None else None
        if ref is not None and ref() is a:
            return a is t or (
                isinstance(a, np.ndarray)
                and t.dtype == a.dtype
                and t.ndim == 1
                and t.strides == a.strides
            )
    return False


def quat_norms(q: F64) -> F64:
    """|q| per row of (N, 4) quaternions, equal to ``np.linalg.norm(q, axis=1)`` to the bit
    (the same sum of squares in the same order, ((x^2 + y^2) + z^2) + w^2), from columns:
    a reduction along rows of 4 is slow in numpy."""
    out = np.multiply(q[:, 0], q[:, 0])
    sq = np.empty_like(out)
    for j in (1, 2, 3):
        np.multiply(q[:, j], q[:, j], out=sq)
        out += sq
    return np.sqrt(out, out=out)


def _check_stamp_range(t: I64, where: str) -> None:
    """Refuse int64 ns stamps beyond +-``MAX_ABS_STAMP_NS`` (their differences could wrap)."""
    lo, hi = int(t.min()), int(t.max())
    if lo < -MAX_ABS_STAMP_NS or hi > MAX_ABS_STAMP_NS:
        bad = int(np.argmax(t)) if hi > MAX_ABS_STAMP_NS else int(np.argmin(t))
        raise PoseStreamError(
            f"{where}: stamp of sample {bad} ({int(t[bad])} ns) is beyond +-{MAX_ABS_STAMP_NS} "
            "ns (about 146 years from 1970): stamp differences would overflow int64"
        )


def _check_float_seconds(t: F64, where: str) -> None:
    """Refuse float stamps that cannot be seconds: too large for int64 nanoseconds (often
    epoch nanoseconds passed as floats, which float64 cannot hold to the nanosecond)."""
    big = np.abs(t)
    j = int(np.argmax(big))
    peak = float(big[j])
    if peak <= MAX_ABS_STAMP_S:
        return
    if 1e15 <= peak <= 1e20:
        raise PoseStreamError(
            f"{where}: stamp of sample {j} is {t[j]:.17g}: float stamps are taken as seconds, "
            "and this looks like epoch nanoseconds stored as floats (float64 cannot hold them "
            "to the nanosecond); pass int64 nanoseconds, or float seconds"
        )
    raise PoseStreamError(
        f"{where}: stamp of sample {j} is {t[j]:.6g} s, beyond +-{MAX_ABS_STAMP_S:.4g} s "
        "(about 146 years from 1970): not a valid time in int64 nanoseconds"
    )


def _describe(topic: str, source: str) -> str:
    if topic and source:
        return f"{source} [{topic}]"
    return source or topic or "pose stream"
