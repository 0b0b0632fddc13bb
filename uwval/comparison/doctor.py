"""Frame doctor: which pose convention is the other (Unity) stream really in?

Given time-aligned samples of the reference (canonical ENU/FLU) and of the other stream as
recorded, it searches all 48 signed axis permutations for the world map A_w (from the
demeaned positions, so a shifted scene origin does not matter; from orientations when the
body does not translate) and then the body map A_b (the signed permutation nearest to the
mean of R_other^T A_w R_ref, same determinant as A_w), names the known convention that
matches (ROS-TCP-Connector FLU, ENU-north, NED), scores every named convention by its
position and rotation error, and warns when the configured one fits worse than another.
This catches the commonest integration bug: the wrong To<...>() map in the Unity script.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from uwval.frames import CONVENTIONS, convention_maps, convert_quaternions, get_convention
from uwval.rotations import geodesic_deg, matrix_from_quat

F64 = NDArray[np.float64]

_AXES = "xyz"

#: Most samples the doctor looks at: longer streams are thinned evenly to at most this many.
#: Its answer is discrete (which of ten conventions, each either exact or off by a whole
#: axis map, judged against 20 % of the motion or ~2 deg), and an RMS over thousands of
#: evenly spaced samples estimates the whole stream's to about 1 % (standard error).
#: Scoring 20,000 or more cost ~20 ms of every compare (most of a 10-minute log's
#: comparison) for no other answer.
DOCTOR_SAMPLES = 4096


def thinning_step(n: int, cap: int = DOCTOR_SAMPLES) -> int:
    """The stride that keeps ``n`` samples to at most ``cap`` (every sample when n <= cap)."""
    return max(1, -(-n // max(1, cap)))


def _build_signed_permutations() -> tuple[F64, ...]:
    out = []
    for perm in itertools.permutations(range(3)):
        for signs in itertools.product((1.0, -1.0), repeat=3):
            m = np.zeros((3, 3))
            for row, (col, sgn) in enumerate(zip(perm, signs, strict=True)):
                m[row, col] = sgn
            m.flags.writeable = False
            out.append(m)
    return tuple(out)


_SIGNED_PERMUTATIONS = _build_signed_permutations()
#: Their determinants (+-1), in the same order.
_PERM_DETS = tuple(float(np.sign(np.linalg.det(a))) for a in _SIGNED_PERMUTATIONS)


def signed_permutations() -> list[F64]:
    """All 48 signed 3x3 permutation matrices (24 proper, 24 improper), read-only."""
    return list(_SIGNED_PERMUTATIONS)


def _mean_body_product(r_oth: F64, aw: F64, r_ref: F64) -> F64:
    """mean over n of R_oth[n]^T A_w R_ref[n] (3x3): one (3, 3N) x (3N, 3) product.

    A_w is a signed permutation, so A_w R_ref is an exact move of rows; the sum over samples
    and rows is one matrix product (the three-operand einsum took ~9 ms per 20,000 samples).
    Only the nearest signed permutation of the result is used (a discrete choice).
    """
    n = r_ref.shape[0]
    ar = aw @ r_ref  # signed row moves: exact
    m: F64 = (r_oth.reshape(3 * n, 3).T @ ar.reshape(3 * n, 3)) / n
    return m


def describe_map(m: F64, src: str = "ros", dst: str = "other") -> str:
    """Human text of a signed permutation: 'other x = -ros y, other y = ros z, ...'."""
    parts = []
    for row in range(3):
        col = int(np.argmax(np.abs(m[row])))
        sign = "-" if m[row, col] < 0 else ""
        parts.append(f"{dst} {_AXES[row]} = {sign}{src} {_AXES[col]}")
    return ", ".join(parts)


@dataclass
class FrameDiagnosis:
    """Result of the frame doctor."""

    best: str | None  # name of the best-fitting known convention (None: no known one fits)
    configured: str
    world_axes: F64  # fitted A_w (reference/canonical -> other)
    body_axes: F64  # fitted A_b
    scores: dict[str, dict[str, float]] = field(default_factory=dict)  # per convention
    warning: str | None = None
    n_samples: int = 0

    def to_json(self) -> dict[str, Any]:
        return {
            "best": self.best,
            "best_description": CONVENTIONS[self.best].description if self.best else None,
            "configured": self.configured,
            "fitted_world_axes": self.world_axes.tolist(),
            "fitted_body_axes": self.body_axes.tolist(),
            "fitted_world_map": describe_map(self.world_axes),
            "fitted_body_map": describe_map(self.body_axes),
            "scores": self.scores,
            "warning": self.warning,
            "n_samples": self.n_samples,
        }


def _fit_world(ref_pos: F64, oth_pos: F64, ref_rot: F64, oth_rot: F64) -> F64:
    cands = signed_permutations()
    rc = ref_pos - ref_pos.mean(axis=0)
    oc = oth_pos - oth_pos.mean(axis=0)
    spread = float(np.sqrt(np.einsum("ij,ij->", rc, rc) / max(1, rc.shape[0])))
    if spread > 1e-6:
        # cost |oc - rc A^T|^2 = const - 2 tr(A^T (oc^T rc)) -> maximise <A, C>
        c = oc.T @ rc
        scores = [float(np.sum(a * c)) for a in cands]
        return cands[int(np.argmax(scores))]
    # no translation: a world map A_w with some body map A_b must satisfy
    # R_oth = A_w R_ref A_b^T for all samples; pick the pair with the smallest residual
    best, best_cost = cands[0], np.inf
    for aw in cands:
        m = _mean_body_product(oth_rot, aw, ref_rot)
        ab = _nearest_perm(m, np.linalg.det(aw))
        resid = oth_rot - aw @ ref_rot @ ab.T
        cost = float(np.einsum("nij,nij->", resid, resid))
        if cost < best_cost:
            best, best_cost = aw, cost
    return best


def _nearest_perm(m: F64, det_sign: float) -> F64:
    sign = np.sign(det_sign)
    cands = [a for a, d in zip(_SIGNED_PERMUTATIONS, _PERM_DETS, strict=True) if d == sign]
    scores = [float(np.sum(a * m)) for a in cands]
    return cands[int(np.argmax(scores))]


def _scores(rp: F64, rq: F64, op: F64, oq: F64) -> dict[str, dict[str, float]]:
    """Per known convention (in :data:`CONVENTIONS` order), the RMS position error (m, mean
    difference removed) and RMS geodesic angle (deg) of the other stream read in it.

    Each convention's world map moves whole columns (a signed permutation), so its position
    error on axis j is s * other[:, k] - reference[:, j], demeaned: the squared sums of the
    18 possible (j, k, s) are computed at most once each, from demeaned columns, instead of
    converting every position per convention (the same sums up to rounding). Orientations
    are converted per convention (:func:`uwval.frames.convert_quaternions`).
    """
    n = max(1, rp.shape[0])
    ref_cols = [rp[:, j] - rp[:, j].mean() for j in range(3)]
    oth_cols = [op[:, k] - op[:, k].mean() for k in range(3)]
    squares: dict[tuple[int, int, float], float] = {}
    out: dict[str, dict[str, float]] = {}
    for name in CONVENTIONS:
        mw, mb = convention_maps(name, "enu")  # the maps convert_arrays(..., name, "enu") uses
        total = 0.0
        for j in range(3):
            k = int(np.argmax(np.abs(mw[j])))
            key = (j, k, float(mw[j, k]))
            if key not in squares:
                d = oth_cols[k] * key[2] - ref_cols[j]
                squares[key] = float(d @ d)
            total += squares[key]
        ang = geodesic_deg(convert_quaternions(oq, mw, mb), rq)
        out[name] = {
            "position_rms_m": float(np.sqrt(total / n)),
            "rotation_rms_deg": float(np.sqrt(np.mean(ang**2))),
        }
    return out


def diagnose(
    ref_pos: F64, ref_quat: F64, oth_pos: F64, oth_quat: F64, configured: str = "enu"
) -> FrameDiagnosis:
    """Find the convention of the other stream from time-aligned samples of both streams.

    ``ref_*`` are canonical ENU/FLU poses; ``oth_*`` the other stream's raw poses (in its own
    unknown convention) at the same instants. Scores are RMS position error (m, after removing
    the mean difference) and RMS geodesic angle (deg) after converting with each convention.
    """
    step = thinning_step(ref_pos.shape[0])  # the fit needs a few thousand samples
    rp, rq, op, oq = ref_pos[::step], ref_quat[::step], oth_pos[::step], oth_quat[::step]
    r_ref = matrix_from_quat(rq)
    r_oth = matrix_from_quat(oq)
    aw = _fit_world(rp, op, r_ref, r_oth)
    m = _mean_body_product(r_oth, aw, r_ref)
    ab = _nearest_perm(m, np.linalg.det(aw))

    scores = _scores(rp, rq, op, oq)

    best = None
    for name, conv in CONVENTIONS.items():
        if np.array_equal(conv.world_axes, aw) and np.array_equal(conv.body_axes, ab):
            best = name
    configured_name = get_convention(configured).name
    # Motion along few axes (a pure surge, no rotation) leaves the map ambiguous: several
    # maps fit equally. Judge by how well each convention fits, relative to the motion.
    rc = rp - rp.mean(axis=0)
    spread = float(np.sqrt(np.einsum("ij,ij->", rc, rc) / max(1, rc.shape[0])))

    def cost(name: str) -> float:
        sc = scores[name]
        return sc["position_rms_m"] / max(spread, 1e-3) + sc["rotation_rms_deg"] / 10.0

    cfg_cost = cost(configured_name)
    cfg_fits = cfg_cost < 0.2  # within 20 % of the motion, or ~2 deg of rotation
    warning = None
    if best is None:
        fitting = sorted((cost(n), n) for n in CONVENTIONS if cost(n) < 0.2)
        if cfg_fits:
            best = configured_name  # ambiguous fit, and the configured map explains the data
        elif fitting:
            best = fitting[0][1]  # ambiguous fit, but a known map explains the data
        else:
            warning = (
                "the other stream matches no known convention: fitted world map "
                f"[{describe_map(aw)}], body map [{describe_map(ab)}]"
            )
    if best is not None and best != configured_name:
        if cfg_fits and cfg_cost <= 2.0 * cost(best) + 0.05:
            best = configured_name  # both fit: the motion cannot tell them apart
        else:
            cfg, bst = scores[configured_name], scores[best]
            warning = (
                f"configured frame {configured_name!r} fits worse than {best!r} "
                f"({CONVENTIONS[best].description}): rotation RMS "
                f"{cfg['rotation_rms_deg']:.3g} deg vs {bst['rotation_rms_deg']:.3g} deg, "
                f"position RMS {cfg['position_rms_m']:.3g} m vs {bst['position_rms_m']:.3g} m"
            )
    return FrameDiagnosis(best, configured_name, aw, ab, scores, warning, int(rp.shape[0]))
