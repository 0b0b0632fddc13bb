"""Relative pose error (RPE) with evo_rpe's semantics, on columnar arrays.

For pose pairs (i, j) chosen by a delta (frames, metres of path, degrees or radians of
rotation; consecutive or all pairs), the error pose is E = (Q_i^-1 Q_j)^-1 (P_i^-1 P_j) with
Q the reference and P the estimate (TUM RGB-D benchmark / evo's ``RPE.rpe_base``). The pose
relations reduce E to one number per pair exactly as ``evo.core.metrics.RPE`` does:

* ``trans_part``: |t_E| (m), ``rot_part``: |R_E - I|_F, ``full``: |E - I|_F,
* ``angle_deg`` / ``angle_rad``: rotation angle of R_E,
* ``point_distance``: | |q_j - q_i| - |p_j - p_i| | (m), ``point_distance_error_ratio``:
  that over |q_j - q_i|, in percent (pairs with zero reference distance are left out).

Everything works on (N, 3) positions and (N, 4) xyzw quaternions: no 4x4 matrices, no
per-pose Python loop. Pair selection by accumulated path or angle (evo walks the poses one by
one, resetting a running sum) is done with cumulative sums, ``searchsorted`` and pointer
doubling over the "next pair start" map.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from uwval.comparison.align import ALIGN_MODES, Alignment, estimate_alignment, identity, umeyama
from uwval.comparison.relations import RELATION_UNITS
from uwval.comparison.stats import norm_stats
from uwval.comparison.sync import associate_nearest
from uwval.errors import AlignmentError, ConfigError
from uwval.frames import convert_stream
from uwval.posestream import PoseStream
from uwval.rotations import geodesic_angle, quat_multiply, rotate_vectors

F64 = NDArray[np.float64]
I64 = NDArray[np.int64]

RELATIONS = tuple(RELATION_UNITS)
#: ``--delta-unit`` letters (evo's ``-u``).
DELTA_UNITS = {"f": "frames", "m": "m", "d": "deg", "r": "rad"}
#: ``align`` values of :func:`rpe`: the compare modes plus ``scale`` (evo's ``-s`` alone).
RPE_ALIGN_MODES = (*ALIGN_MODES, "scale")
#: Rows of the all-pairs angle search done per step (each row compares with every later pose).
_ANGLE_BLOCK_ELEMENTS = 1 << 20


@dataclass(frozen=True)
class RpeResult:
    """Relative pose errors of one trajectory pair and evo's statistics of them.

    ``first`` / ``second`` index the associated (matched) poses; ``t`` holds the reference
    stamps (ns) of the second pose of each pair; ``errors`` are in ``unit``.
    """

    relation: str
    unit: str
    delta: float
    delta_unit: str
    all_pairs: bool
    pairs_from_reference: bool
    first: I64
    second: I64
    t: I64
    errors: F64
    stats: dict[str, float]
    alignment: Alignment
    n_poses: int
    sync: dict[str, Any] = field(default_factory=dict)
    warnings: tuple[str, ...] = ()

    @property
    def n_pairs(self) -> int:
        return int(self.errors.shape[0])

    def to_json(self) -> dict[str, Any]:
        """The statistics and settings (no per-pair arrays), as ``uwval rpe --json`` prints."""
        return {
            "metric": "rpe",
            "pose_relation": self.relation,
            "unit": self.unit,
            "delta": self.delta,
            "delta_unit": DELTA_UNITS[self.delta_unit],
            "all_pairs": self.all_pairs,
            "pairs_from_reference": self.pairs_from_reference,
            "n_poses": self.n_poses,
            "n_pairs": self.n_pairs,
            "stats": dict(self.stats),
            "alignment": self.alignment.to_json(),
            "sync": dict(self.sync),
            "warnings": list(self.warnings),
        }


# ----------------------------------------------------------------------------- pair selection
def pairs_by_index(n: int, delta: int, all_pairs: bool = False) -> tuple[I64, I64]:
    """evo's ``filter_pairs_by_index``: (i, i + delta) for every i, or i = 0, delta, 2 delta..."""
    if all_pairs:
        i = np.arange(max(n - delta, 0), dtype=np.int64)
        return i, i + delta
    ids = np.arange(0, n, delta, dtype=np.int64)
    return ids[:-1], ids[1:]


def _chain(cum: F64, delta: float) -> I64:
    """Indices 0 = a_0 < a_1 < ... with a_{k+1} the first j > a_k where cum[j] - cum[a_k] >= delta.

    ``cum`` is non-decreasing (accumulated steps, cum[0] = 0). This is evo's walk that sums
    steps and starts over at each accepted pose; the successor map is one ``searchsorted`` and
    the walk from 0 is followed by pointer doubling (log2 N vectorised passes).
    """
    n = cum.shape[0]
    nxt = np.empty(n + 1, dtype=np.int64)
    nxt[:n] = np.searchsorted(cum, cum + delta, side="left")
    np.maximum(nxt[:n], np.arange(1, n + 1), out=nxt[:n])  # always move forward
    np.minimum(nxt, n, out=nxt)
    nxt[n] = n
    # upper bound on the chain's length: each hop covers >= delta (cum[-1] / delta + 1 hops)
    bound = n + 1
    if delta > 0 and math.isfinite(float(cum[-1])):
        bound = min(bound, int(float(cum[-1]) / delta) + 3)
    while True:
        m = np.arange(bound, dtype=np.int64)
        pos = np.zeros(bound, dtype=np.int64)
        jump = nxt
        k = 0
        while (1 << k) < bound:
            sel = ((m >> k) & 1).astype(bool)
            pos[sel] = jump[pos[sel]]
            jump = jump[jump]
            k += 1
        if pos[-1] == n or bound == n + 1:
            kept: NDArray[np.int64] = pos[pos < n]
            return kept
        bound = n + 1  # rounding made the estimate too short: take the safe bound


def pairs_by_path(
    position: F64, delta: float, tol: float, all_pairs: bool = False
) -> tuple[I64, I64]:
    """evo's ``filter_pairs_by_path``: pairs ``delta`` metres of travelled path apart.

    Consecutive: accumulate step lengths from a start pose until >= delta, start over there.
    All pairs: for each i, the j > i whose path from i is nearest to delta (first of equals),
    kept when within ``tol``.
    """
    steps = np.sqrt(np.einsum("ij,ij->i", np.diff(position, axis=0), np.diff(position, axis=0)))
    cum = np.concatenate([[0.0], np.cumsum(steps)])
    if not all_pairs:
        ids = _chain(cum, delta)
        return ids[:-1], ids[1:]
    return _nearest_pairs(cum, delta, tol)


def _nearest_pairs(cum: F64, delta: float, tol: float) -> tuple[I64, I64]:
    """For each i < n-1: the first j > i minimising |(cum[j] - cum[i]) - delta|, if <= tol."""
    n = cum.shape[0]
    i = np.arange(n - 1, dtype=np.int64)
    hi = np.searchsorted(cum, cum[:-1] + delta, side="left")
    # the minimum of the V-shaped |(cum[j] - cum[i]) - delta| lies next to the crossing;
    # look at a few neighbours (rounding of cum[i] + delta) with evo's exact expression
    cand = np.stack([hi - 2, hi - 1, hi, hi + 1], axis=1)
    cand = np.clip(cand, (i + 1)[:, None], n - 1)
    err = np.abs((cum[cand] - cum[:-1, None]) - delta)
    best = cand[i, np.argmin(err, axis=1)]  # argmin: lowest candidate among equal errors
    best_err = err[i, np.argmin(err, axis=1)]
    # equal cumulative distances (standing still) have equal errors: evo takes the first
    first = np.searchsorted(cum, cum[best], side="left")
    best = np.maximum(first, i + 1)
    keep = best_err <= tol
    return i[keep], best[keep]


def pairs_by_angle(
    orientation: F64, delta: float, tol: float, degrees: bool, all_pairs: bool = False
) -> tuple[I64, I64]:
    """evo's ``filter_pairs_by_angle``: pairs ``delta`` (rad, or deg) of rotation apart.

    Consecutive: accumulated angle between successive orientations, started over at each pair.
    All pairs: every (i, j > i) whose direct relative angle is within delta +- tol.
    """
    lo_b, hi_b = (0.0, 180.0) if degrees else (0.0, math.pi)
    if not lo_b <= delta <= hi_b:
        raise ConfigError(f"--delta: an angle delta must be within [{lo_b}, {hi_b:g}], got {delta}")
    if degrees:
        delta, tol = math.radians(delta), math.radians(tol)
    q = orientation
    if not all_pairs:
        steps = geodesic_angle(q[1:], q[:-1])
        ids = _chain(np.concatenate([[0.0], np.cumsum(steps)]), delta)
        return ids[:-1], ids[1:]
    n = q.shape[0]
    lower, upper = delta - tol, delta + tol
    out_i: list[I64] = []
    out_j: list[I64] = []
    rows = max(1, _ANGLE_BLOCK_ELEMENTS // max(n, 1))
    for start in range(0, n - 1, rows):  # blocks of rows: each a vectorised (rows, n) pass
        ii = np.arange(start, min(start + rows, n - 1), dtype=np.int64)
        ang = geodesic_angle(q[None, :, :], q[ii][:, None, :])
        ok = (ang >= lower) & (ang <= upper) & (np.arange(n)[None, :] > ii[:, None])
        r, c = np.nonzero(ok)
        out_i.append(ii[r])
        out_j.append(c.astype(np.int64))
    if not out_i:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    return np.concatenate(out_i), np.concatenate(out_j)


def select_pairs(
    position: F64,
    orientation: F64,
    delta: float,
    delta_unit: str,
    rel_tol: float = 0.1,
    all_pairs: bool = False,
) -> tuple[I64, I64]:
    """evo's ``id_pairs_from_delta`` on the poses given (evo: the estimate's, by default)."""
    if delta_unit not in DELTA_UNITS:
        raise ConfigError(
            f"--delta-unit {delta_unit!r}: choose f (frames), m (metres), d (deg) or r (rad)"
        )
    if not (delta >= 0 and math.isfinite(delta)):
        raise ConfigError(f"--delta must be a non-negative number, got {delta}")
    n = position.shape[0]
    if delta_unit == "f":
        if not float(delta).is_integer() or delta < 1:
            raise ConfigError(f"--delta must be a whole number >= 1 of frames, got {delta}")
        i, j = pairs_by_index(n, int(delta), all_pairs)
    elif delta_unit == "m":
        i, j = pairs_by_path(position, delta, delta * rel_tol, all_pairs)
    else:
        i, j = pairs_by_angle(orientation, delta, delta * rel_tol, delta_unit == "d", all_pairs)
    if i.size == 0:
        raise AlignmentError(
            f"delta = {delta:g} ({DELTA_UNITS[delta_unit]}) produced no pose pair among {n} poses: "
            "try a lower value or a less strict tolerance"
        )
    return i, j


# ----------------------------------------------------------------------------- error values
def relative_errors(
    ref_pos: F64,
    ref_quat: F64,
    est_pos: F64,
    est_quat: F64,
    i: I64,
    j: I64,
    relation: str,
) -> tuple[F64, F64 | None]:
    """Error per pair (i, j) under ``relation``; second value: reference distances (ratio only).

    |t_E| = |t_P - t_Q| with t_Q = R(Q_i)^T (q_j - q_i) (rotating by R(Q_rel)^T keeps norms);
    |R_E - I|_F = 2 sqrt(2) sin(theta / 2) for the angle theta of R_E.
    """
    if relation not in RELATION_UNITS:
        raise ConfigError(f"--pose-relation {relation!r}: choose one of {', '.join(RELATIONS)}")
    if relation in ("point_distance", "point_distance_error_ratio"):
        d_ref = np.linalg.norm(ref_pos[j] - ref_pos[i], axis=1)
        d_est = np.linalg.norm(est_pos[j] - est_pos[i], axis=1)
        return np.abs(d_ref - d_est), d_ref
    inv_qi = ref_quat[i] * np.array([-1.0, -1.0, -1.0, 1.0])
    inv_pi = est_quat[i] * np.array([-1.0, -1.0, -1.0, 1.0])
    trans = None
    if relation in ("trans_part", "full"):
        t_q = rotate_vectors(inv_qi, ref_pos[j] - ref_pos[i])
        t_p = rotate_vectors(inv_pi, est_pos[j] - est_pos[i])
        trans = np.linalg.norm(t_p - t_q, axis=1)
        if relation == "trans_part":
            return trans, None
    rel_q = quat_multiply(inv_qi, ref_quat[j])
    rel_p = quat_multiply(inv_pi, est_quat[j])
    angle = geodesic_angle(rel_p, rel_q)  # angle of R_E = R(Q_rel)^T R(P_rel)
    if relation == "angle_rad":
        return angle, None
    if relation == "angle_deg":
        return np.degrees(angle), None
    rot = 2.0 * math.sqrt(2.0) * np.sin(angle / 2.0)
    if relation == "rot_part":
        return rot, None
    assert trans is not None
    return np.sqrt(rot * rot + trans * trans), None


# ----------------------------------------------------------------------------- the metric
def _alignment(
    mode: str, n_to_align: int, ref_pos: F64, ref_quat: F64, est_pos: F64, est_quat: F64
) -> Alignment:
    """evo_rpe's alignment: ``-a`` se3, ``-as`` sim3, ``-s`` scale only, ``--align_origin``."""
    if mode not in RPE_ALIGN_MODES:
        raise ConfigError(f"--align {mode!r}: choose one of {', '.join(RPE_ALIGN_MODES)}")
    if mode == "none":
        return identity()
    if n_to_align != -1 and mode != "origin":
        if n_to_align < 1:
            raise ConfigError(f"--n-to-align must be >= 1 (or -1 for all), got {n_to_align}")
        ref_pos, ref_quat = ref_pos[:n_to_align], ref_quat[:n_to_align]
        est_pos, est_quat = est_pos[:n_to_align], est_quat[:n_to_align]
    if mode == "scale":
        _, _, s = umeyama(est_pos, ref_pos, with_scale=True)
        return Alignment("scale", np.eye(3), np.zeros(3), s)
    return estimate_alignment(mode, ref_pos, ref_quat, est_pos, est_quat)


@dataclass(frozen=True)
class RpeSettings:
    """How :func:`rpe` pairs, aligns and measures (evo_rpe's options; see :func:`rpe`)."""

    relation: str = "trans_part"
    delta: float = 1.0
    delta_unit: str = "f"
    delta_tol: float = 0.1
    all_pairs: bool = False
    pairs_from_reference: bool = False
    align: str = "none"
    n_to_align: int = -1
    sync: str = "nearest"
    max_diff: float = 0.01
    offset: float = 0.0


def rpe(
    reference: PoseStream,
    other: PoseStream,
    settings: RpeSettings | None = None,
    **options: Any,
) -> RpeResult:
    """evo_rpe on two streams: associate (evo's nearest stamps), align, pick pairs, reduce.

    ``options`` are fields of :class:`RpeSettings` (they override ``settings``): evo's pose
    ``relation``, ``delta`` in ``delta_unit`` within ``delta_tol``, ``all_pairs``,
    ``pairs_from_reference``, ``align`` / ``n_to_align``, ``sync``, ``max_diff`` (s) and
    ``offset`` (s). ``sync='none'`` pairs poses by index (evo's behaviour for KITTI files,
    which have no stamps) and refuses streams of different lengths. ``offset`` (s) is added
    to the other stream's stamps for the association (evo's ``--t_offset``). ``other`` is
    converted from its frame convention to ENU first, as ``compare`` does.
    """
    st = settings or RpeSettings()
    if options:
        unknown = sorted(set(options) - set(RpeSettings.__dataclass_fields__))
        if unknown:
            raise TypeError(f"rpe() got unexpected keyword argument(s) {unknown}")
        st = replace(st, **options)
    relation, delta, delta_unit, delta_tol = st.relation, st.delta, st.delta_unit, st.delta_tol
    all_pairs, pairs_from_reference, align = st.all_pairs, st.pairs_from_reference, st.align
    n_to_align, sync, max_diff, offset = st.n_to_align, st.sync, st.max_diff, st.offset
    if relation not in RELATION_UNITS:
        raise ConfigError(f"--pose-relation {relation!r}: choose one of {', '.join(RELATIONS)}")
    if not (max_diff >= 0 and math.isfinite(max_diff)):
        raise ConfigError(f"--max-diff must be a non-negative number of seconds, got {max_diff}")
    if not math.isfinite(offset):
        raise ConfigError(f"--t-offset must be a finite number of seconds, got {offset}")
    ref = convert_stream(reference, "enu")
    oth = convert_stream(other, "enu")
    sync_info: dict[str, Any] = {"method": sync, "n_reference": len(ref), "n_other": len(oth)}
    if sync == "nearest":
        match = associate_nearest(ref, oth, max_diff=max_diff, offset=offset)
        ri, oi = match.ref_idx, match.other_idx
        sync_info.update(max_diff_s=max_diff, offset_s=offset, matched=int(ri.size))
        ref_pos, ref_quat, t = ref.position[ri], ref.orientation[ri], ref.t[ri]
        est_pos, est_quat = oth.position[oi], oth.orientation[oi]
    elif sync == "none":
        if len(ref) != len(oth):
            raise AlignmentError(
                f"{ref.describe()} has {len(ref)} poses and {oth.describe()} {len(oth)}: "
                "poses without stamps are paired by index and need equal counts"
            )
        ref_pos, ref_quat, t = ref.position, ref.orientation, ref.t
        est_pos, est_quat = oth.position, oth.orientation
        sync_info["matched"] = len(ref)
    else:
        raise ConfigError(f"--sync {sync!r}: rpe associates by nearest stamp (or 'none')")
    al = _alignment(align, n_to_align, ref_pos, ref_quat, est_pos, est_quat)
    est_pos, est_quat = al.apply(est_pos, est_quat)
    src_pos, src_quat = (ref_pos, ref_quat) if pairs_from_reference else (est_pos, est_quat)
    i, j = select_pairs(src_pos, src_quat, delta, delta_unit, delta_tol, all_pairs)
    errors, d_ref = relative_errors(ref_pos, ref_quat, est_pos, est_quat, i, j, relation)
    warnings: list[str] = []
    if relation == "point_distance_error_ratio":
        assert d_ref is not None
        nonzero = d_ref != 0
        if not nonzero.all():
            warnings.append(
                f"left out {int((~nonzero).sum())} pair(s) with zero reference distance "
                "(ratio undefined)"
            )
        i, j = i[nonzero], j[nonzero]
        errors = errors[nonzero] / d_ref[nonzero] * 100
    if errors.size == 0:
        raise AlignmentError("no pose pair left to compute the RPE from")
    return RpeResult(
        relation=relation,
        unit=RELATION_UNITS[relation],
        delta=float(delta),
        delta_unit=delta_unit,
        all_pairs=all_pairs,
        pairs_from_reference=pairs_from_reference,
        first=i,
        second=j,
        t=t[j],
        errors=errors,
        stats=norm_stats(errors),
        alignment=al,
        n_poses=int(ref_pos.shape[0]),
        sync=sync_info,
        warnings=tuple(warnings),
    )
