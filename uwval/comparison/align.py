"""Spatial alignment of the other stream onto the reference, as evo does it (Umeyama 1991).

``none``: nothing; ``se3``: rotation + translation; ``sim3``: plus scale; ``origin``: the
transform that makes the first other pose coincide with the first reference pose
(``T_ref0 T_other0^-1``). The transform is applied to the other stream after association:
p' = s R p + t, R' = R_a R_other. Computed on arrays, without lists of 4x4 matrices.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from uwval.compat import StrEnum
from uwval.errors import AlignmentError
from uwval.rotations import matrix_from_quat, quat_from_matrix, quat_multiply

F64 = NDArray[np.float64]


class AlignMode(StrEnum):
    """Spatial alignment modes (a StrEnum: each equals its CLI string, ``"se3"``...)."""

    NONE = "none"
    SE3 = "se3"
    SIM3 = "sim3"
    ORIGIN = "origin"


ALIGN_MODES = tuple(m.value for m in AlignMode)


@dataclass(frozen=True)
class Alignment:
    """A similarity transform applied to the other stream: p' = scale * R p + t."""

    mode: str
    rotation: F64  # (3, 3)
    translation: F64  # (3,)
    scale: float = 1.0

    def apply(self, position: F64, orientation: F64) -> tuple[F64, F64]:
        """Transform (N, 3) positions and (N, 4) xyzw orientations."""
        if self.mode == "none":
            return position, orientation
        # column by column instead of a BLAS matmul: an (N, 3) @ (3, 3) product gains nothing
        # from BLAS threads and suffers badly from them on a loaded machine
        r = self.rotation * self.scale
        pos = np.empty_like(position)
        for i in range(3):
            pos[:, i] = (
                r[i, 0] * position[:, 0]
                + r[i, 1] * position[:, 1]
                + r[i, 2] * position[:, 2]
                + self.translation[i]
            )
        q_a = quat_from_matrix(self.rotation[None])[0]
        quat = quat_multiply(np.broadcast_to(q_a, orientation.shape), orientation)
        return pos, quat

    def to_json(self) -> dict[str, Any]:
        return {
            "mode": self.mode,
            "rotation": self.rotation.tolist(),
            "translation": self.translation.tolist(),
            "scale": self.scale,
        }


def identity() -> Alignment:
    return Alignment("none", np.eye(3), np.zeros(3), 1.0)


def umeyama(x: F64, y: F64, with_scale: bool = False) -> tuple[F64, F64, float]:
    """Least-squares R, t, c with y ~ c R x + t for (N, 3) point sets (evo's formulation).

    Same steps as ``evo.core.geometry.umeyama_alignment`` (means, variance of x, covariance
    1/n sum (y - my)(x - mx)^T, SVD, Kabsch sign fix), with the covariance as one matrix
    product instead of a per-point loop.
    """
    if x.shape != y.shape or x.ndim != 2 or x.shape[1] != 3:
        raise AlignmentError(f"umeyama needs two (N, 3) arrays, got {x.shape} and {y.shape}")
    n = x.shape[0]
    if n < 3:
        raise AlignmentError(f"alignment needs at least 3 matched poses, got {n}")
    mean_x = x.mean(axis=0)
    mean_y = y.mean(axis=0)
    xc = x - mean_x
    yc = y - mean_y
    sigma_x = float(np.einsum("ij,ij->", xc, xc)) / n
    cov_xy = np.einsum("ni,nj->ij", yc, xc) / n  # no BLAS threads for a 3x3 result
    if not bool(np.isfinite(cov_xy).all()) or not math.isfinite(sigma_x):
        raise AlignmentError(
            "alignment covariance is not finite (positions NaN/inf or too large to square)"
        )
    try:
        u, d, v = np.linalg.svd(cov_xy)
    except np.linalg.LinAlgError as exc:
        raise AlignmentError(f"Umeyama alignment failed: {exc}") from None
    if np.count_nonzero(d > np.finfo(d.dtype).eps) < 2:
        raise AlignmentError(
            "degenerate covariance rank (motion along a line or a point): "
            "Umeyama alignment is not possible"
        )
    s = np.eye(3)
    if np.linalg.det(u) * np.linalg.det(v) < 0.0:
        s[2, 2] = -1  # keep a proper rotation (Kabsch)
    r = u @ s @ v
    c = float(np.trace(np.diag(d) @ s) / sigma_x) if with_scale else 1.0
    t = mean_y - c * (r @ mean_x)
    return r, t, c


def estimate_alignment(
    mode: AlignMode | str, ref_pos: F64, ref_quat: F64, oth_pos: F64, oth_quat: F64
) -> Alignment:
    """The alignment ``mode`` (an :class:`AlignMode` or its string) that maps the (associated)
    other poses onto the reference."""
    if mode not in ALIGN_MODES:
        raise AlignmentError(
            f"unknown alignment {mode!r}; choose one of {', '.join(ALIGN_MODES)} "
            "(or scale: evo's -s alone)"
        )
    mode = AlignMode(mode).value
    if mode == "none":
        return identity()
    if mode in ("se3", "sim3"):
        r, t, c = umeyama(oth_pos, ref_pos, with_scale=mode == "sim3")
        return Alignment(mode, r, t, c)
    # origin: T = T_ref0 @ inv(T_oth0)
    r_ref = matrix_from_quat(ref_quat[:1])[0]
    r_oth = matrix_from_quat(oth_quat[:1])[0]
    r = r_ref @ r_oth.T
    t = ref_pos[0] - r @ oth_pos[0]
    return Alignment("origin", r, t, 1.0)
