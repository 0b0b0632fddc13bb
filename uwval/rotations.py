"""Vectorised rotation helpers on (N, 4) quaternions in (x, y, z, w) order.

All functions take and return numpy arrays and loop over nothing in Python, so they serve
hot paths on millions of poses. Angles are radians unless a name says ``deg``.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

F64 = NDArray[np.float64]


def matrix_from_quat(q: F64) -> F64:
    """(N, 4) unit quaternions (x, y, z, w) -> (N, 3, 3) rotation matrices."""
    q = np.asarray(q, dtype=np.float64)
    x, y, z, w = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    xx, yy, zz = x * x, y * y, z * z
    xy, xz, yz = x * y, x * z, y * z
    wx, wy, wz = w * x, w * y, w * z
    m = np.empty((*q.shape[:-1], 3, 3))
    m[..., 0, 0] = 1 - 2 * (yy + zz)
    m[..., 0, 1] = 2 * (xy - wz)
    m[..., 0, 2] = 2 * (xz + wy)
    m[..., 1, 0] = 2 * (xy + wz)
    m[..., 1, 1] = 1 - 2 * (xx + zz)
    m[..., 1, 2] = 2 * (yz - wx)
    m[..., 2, 0] = 2 * (xz - wy)
    m[..., 2, 1] = 2 * (yz + wx)
    m[..., 2, 2] = 1 - 2 * (xx + yy)
    return m


def quat_from_matrix(m: F64) -> F64:
    """(N, 3, 3) rotation matrices -> (N, 4) unit quaternions (x, y, z, w), w >= 0.

    Uses the numerically stable branch selection of Shepperd's method, vectorised.
    """
    m = np.asarray(m, dtype=np.float64)
    tr = m[..., 0, 0] + m[..., 1, 1] + m[..., 2, 2]
    diag = np.stack([m[..., 0, 0], m[..., 1, 1], m[..., 2, 2], tr], axis=-1)
    k = np.argmax(diag, axis=-1)
    q = np.empty((*m.shape[:-2], 4))
    # candidate for each branch; pick per sample (cheap: 4 vectorised evaluations)
    cands = np.empty((4, *q.shape))
    s = np.sqrt(np.maximum(1 + m[..., 0, 0] - m[..., 1, 1] - m[..., 2, 2], 1e-300)) * 2
    cands[0] = np.stack(
        [
            0.25 * s,
            (m[..., 0, 1] + m[..., 1, 0]) / s,
            (m[..., 0, 2] + m[..., 2, 0]) / s,
            (m[..., 2, 1] - m[..., 1, 2]) / s,
        ],
        axis=-1,
    )
    s = np.sqrt(np.maximum(1 + m[..., 1, 1] - m[..., 0, 0] - m[..., 2, 2], 1e-300)) * 2
    cands[1] = np.stack(
        [
            (m[..., 0, 1] + m[..., 1, 0]) / s,
            0.25 * s,
            (m[..., 1, 2] + m[..., 2, 1]) / s,
            (m[..., 0, 2] - m[..., 2, 0]) / s,
        ],
        axis=-1,
    )
    s = np.sqrt(np.maximum(1 + m[..., 2, 2] - m[..., 0, 0] - m[..., 1, 1], 1e-300)) * 2
    cands[2] = np.stack(
        [
            (m[..., 0, 2] + m[..., 2, 0]) / s,
            (m[..., 1, 2] + m[..., 2, 1]) / s,
            0.25 * s,
            (m[..., 1, 0] - m[..., 0, 1]) / s,
        ],
        axis=-1,
    )
    s = np.sqrt(np.maximum(1 + tr, 1e-300)) * 2
    cands[3] = np.stack(
        [
            (m[..., 2, 1] - m[..., 1, 2]) / s,
            (m[..., 0, 2] - m[..., 2, 0]) / s,
            (m[..., 1, 0] - m[..., 0, 1]) / s,
            0.25 * s,
        ],
        axis=-1,
    )
    q = np.take_along_axis(np.moveaxis(cands, 0, -2), k[..., None, None], axis=-2)[..., 0, :]
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    out: F64 = np.where(q[..., 3:4] < 0, -q, q)
    return out


def quat_multiply(a: F64, b: F64) -> F64:
    """Hamilton product a * b of (N, 4) quaternions (x, y, z, w)."""
    ax, ay, az, aw = np.moveaxis(np.asarray(a, dtype=np.float64), -1, 0)
    bx, by, bz, bw = np.moveaxis(np.asarray(b, dtype=np.float64), -1, 0)
    return np.stack(
        [
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
            aw * bw - ax * bx - ay * by - az * bz,
        ],
        axis=-1,
    )


def rotate_vectors(q: F64, v: F64) -> F64:
    """Rotate (N, 3) vectors by (N, 4) quaternions: R(q) v."""
    q = np.asarray(q, dtype=np.float64)
    u = q[..., :3]
    w = q[..., 3:4]
    t = 2.0 * np.cross(u, v)
    return np.asarray(v + w * t + np.cross(u, t))


def rpy_from_quat(q: F64) -> F64:
    """ROS roll, pitch, yaw (fixed-axis XYZ, R = Rz(yaw) Ry(pitch) Rx(roll)), radians, (N, 3)."""
    q = np.asarray(q, dtype=np.float64)
    x, y, z, w = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    roll = np.arctan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    sinp = np.clip(2 * (w * y - z * x), -1.0, 1.0)
    pitch = np.arcsin(sinp)
    yaw = np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    return np.stack([roll, pitch, yaw], axis=-1)


def quat_from_rpy(rpy: F64) -> F64:
    """Inverse of :func:`rpy_from_quat`: (N, 3) roll, pitch, yaw (rad) -> (N, 4) (x, y, z, w)."""
    rpy = np.asarray(rpy, dtype=np.float64)
    hr, hp, hy = rpy[..., 0] / 2, rpy[..., 1] / 2, rpy[..., 2] / 2
    cr, sr, cp, sp, cy, sy = np.cos(hr), np.sin(hr), np.cos(hp), np.sin(hp), np.cos(hy), np.sin(hy)
    return np.stack(
        [
            sr * cp * cy - cr * sp * sy,
            cr * sp * cy + sr * cp * sy,
            cr * cp * sy - sr * sp * cy,
            cr * cp * cy + sr * sp * sy,
        ],
        axis=-1,
    )


def rotation_angle(q: F64) -> F64:
    """Geodesic angle (rad, in [0, pi]) of each rotation q; sign of q does not matter."""
    q = np.asarray(q, dtype=np.float64)
    return np.asarray(2.0 * np.arctan2(np.linalg.norm(q[..., :3], axis=-1), np.abs(q[..., 3])))


def geodesic_angle(a: F64, b: F64) -> F64:
    """Angle (rad, [0, pi]) of the rotation between orientations a and b (xyzw), up to sign.

    Computed from the relative quaternion r = conj(b) a as 2 atan2(|r_xyz|, |r_w|): exact 0
    for equal orientations and accurate for small angles, and independent of the quaternions'
    norms. (2 arccos(|a . b|) loses half the digits near 0: quaternions read from text with
    9 decimals, |q|^2 = 1 +- 1e-9, gave a false 0.005 deg between identical orientations.)
    """
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    ax, ay, az, aw = a[..., 0], a[..., 1], a[..., 2], a[..., 3]
    bx, by, bz, bw = b[..., 0], b[..., 1], b[..., 2], b[..., 3]
    w = bw * aw + bx * ax + by * ay + bz * az
    # vector part of conj(b) a: bw a_v - aw b_v - b_v x a_v
    vx = bw * ax - aw * bx - (by * az - bz * ay)
    vy = bw * ay - aw * by - (bz * ax - bx * az)
    vz = bw * az - aw * bz - (bx * ay - by * ax)
    return np.asarray(2.0 * np.arctan2(np.sqrt(vx * vx + vy * vy + vz * vz), np.abs(w)))


def slerp(q0: F64, q1: F64, s: F64) -> F64:
    """Spherical linear interpolation between (N, 4) q0 and q1 at fractions s in [0, 1].

    Takes the short arc (flips q1 when q0 . q1 < 0); falls back to normalised lerp for
    nearly equal quaternions, where slerp is numerically ill-conditioned.
    """
    q0 = np.asarray(q0, dtype=np.float64)
    q1 = np.asarray(q1, dtype=np.float64)
    s = np.asarray(s, dtype=np.float64)[..., None]
    dot = np.sum(q0 * q1, axis=-1, keepdims=True)
    q1 = np.where(dot < 0, -q1, q1)
    dot = np.abs(dot)
    theta = np.arccos(np.clip(dot, -1.0, 1.0))
    sin_t = np.sin(theta)
    small = sin_t < 1e-9
    safe = np.where(small, 1.0, sin_t)
    w0 = np.where(small, 1.0 - s, np.sin((1.0 - s) * theta) / safe)
    w1 = np.where(small, s, np.sin(s * theta) / safe)
    out = w0 * q0 + w1 * q1
    return np.asarray(out / np.linalg.norm(out, axis=-1, keepdims=True))


def wrap_deg(a: F64) -> F64:
    """Wrap angles in degrees to (-180, 180]: 359 vs 1 deg differ by -2, not 358.

    Subtracts the nearest multiple of 360 (faster than np.mod on large arrays), then moves
    the two edges into the half-open range.
    """
    a = np.asarray(a, dtype=np.float64)
    w = np.atleast_1d(a - 360.0 * np.round(a / 360.0))
    w[w <= -180.0] += 360.0
    w[w > 180.0] -= 360.0
    return w.reshape(a.shape)


def slerp_segments(
    q0: F64,
    q1: F64,
    s: F64,
    seg: NDArray[np.intp] | NDArray[np.int64] | None = None,
    *,
    out: F64 | None = None,
) -> F64:
    """``slerp(q0[seg], q1[seg], s)`` for (M, 4) endpoint pairs and (K,) fractions ``s``.

    The same arithmetic as :func:`slerp`, operation for operation (equal to it to the bit),
    arranged for interpolation: what depends on the pair only (the dot product, the short-arc
    sign, the angle and its sine) is computed once per pair, then gathered for the K
    fractions by ``seg`` (indices into the M pairs; ``None``: pair i for fraction i); the
    rest runs on (4, K) component rows (no (K, 1) x (K, 4) broadcasts, slow in numpy). The
    short-arc flip of q1 is a flip of its weight (exact: only the sign changes). Returns the
    (K, 4) unit quaternions (x, y, z, w), written into ``out`` when given.
    """
    a0 = np.asarray(q0, dtype=np.float64).T
    a1 = np.asarray(q1, dtype=np.float64).T
    s = np.asarray(s, dtype=np.float64)
    # dot product summed in numpy's order for a row of 4 (((a + b) + c) + d)
    dot = a0[0] * a1[0]
    for j in (1, 2, 3):
        dot += a0[j] * a1[j]
    flip = dot < 0
    np.abs(dot, out=dot)
    np.clip(dot, -1.0, 1.0, out=dot)
    theta = np.arccos(dot, out=dot)
    safe = np.sin(theta)
    small = safe < 1e-9
    safe[small] = 1.0
    if seg is not None:
        theta, safe, small, flip = theta[seg], safe[seg], small[seg], flip[seg]
        g0, g1 = np.take(a0, seg, axis=1), np.take(a1, seg, axis=1)
    else:
        g0, g1 = a0.copy(), a1.copy()
    one_minus = 1.0 - s
    w0 = np.multiply(one_minus, theta)
    np.sin(w0, out=w0)
    w0 /= safe
    w1 = np.multiply(s, theta)
    np.sin(w1, out=w1)
    w1 /= safe
    if small.any():
        np.copyto(w0, one_minus, where=small)
        np.copyto(w1, s, where=small)
    np.negative(w1, out=w1, where=flip)
    g0 *= w0
    g1 *= w1
    g0 += g1
    # norm as np.linalg.norm sums a row of 4: ((x^2 + y^2) + z^2) + w^2
    norm = np.multiply(g0[0], g0[0])
    for j in (1, 2, 3):
        np.multiply(g0[j], g0[j], out=w1)
        norm += w1
    np.sqrt(norm, out=norm)
    g0 /= norm
    if out is None:
        return np.ascontiguousarray(g0.T)
    out[...] = g0.T
    return out


class Scratch:
    """float64 work buffers of ``k`` elements, reused by every step of a chunked loop (the
    steps' operations write into them: no allocation per operation); ``get(i, m)`` is the
    first ``m`` elements of buffer ``i``."""

    def __init__(self, k: int) -> None:
        self.k = k
        self._bufs: list[F64] = []

    def get(self, i: int, k: int) -> F64:
        while len(self._bufs) <= i:
            self._bufs.append(np.empty(self.k))
        return self._bufs[i][:k]


def geodesic_deg_into(a: F64, b: F64, out: F64, sc: Scratch) -> None:
    """:func:`geodesic_angle` (a, b) in degrees into ``out``, operation for
    operation (equal to the bit), on (k, 4) xyzw rows without allocating temporaries."""
    k = a.shape[0]
    ax, ay, az, aw = a[:, 0], a[:, 1], a[:, 2], a[:, 3]
    bx, by, bz, bw = b[:, 0], b[:, 1], b[:, 2], b[:, 3]
    w, t, u, v, acc = (sc.get(i, k) for i in range(5))
    # w = bw aw + bx ax + by ay + bz az (left to right)
    np.multiply(bw, aw, out=w)
    for p, r in ((bx, ax), (by, ay), (bz, az)):
        np.multiply(p, r, out=t)
        w += t
    # v = bw a_v - aw b_v - (b_v x a_v), component by component; acc = |v|^2
    for i, (a_i, b_i, b_j, a_k, b_k, a_j) in enumerate(
        ((ax, bx, by, az, bz, ay), (ay, by, bz, ax, bx, az), (az, bz, bx, ay, by, ax))
    ):
        np.multiply(bw, a_i, out=v)
        np.multiply(aw, b_i, out=t)
        v -= t
        np.multiply(b_j, a_k, out=t)
        np.multiply(b_k, a_j, out=u)
        t -= u
        v -= t
        if i == 0:
            np.multiply(v, v, out=acc)
        else:
            np.multiply(v, v, out=t)
            acc += t
    np.sqrt(acc, out=acc)
    np.abs(w, out=w)
    np.arctan2(acc, w, out=out)
    out *= 2.0
    np.degrees(out, out=out)


def geodesic_deg(a: F64, b: F64, *, chunk: int = 1 << 14) -> F64:
    """``np.degrees(geodesic_angle(a, b))`` for (N, 4) xyzw arrays, equal to it to the bit,
    in steps of ``chunk`` rows with reused buffers (no (N,) temporary per operation)."""
    n = a.shape[0]
    out = np.empty(n)
    sc = Scratch(min(n, chunk))
    for s in range(0, n, chunk):
        e = min(n, s + chunk)
        geodesic_deg_into(a[s:e], b[s:e], out[s:e], sc)
    return out
