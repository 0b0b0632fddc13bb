"""Pose conventions and conversions between them (DESIGN.md section 3).

A convention is a pair of signed axis permutations relative to uwval's canonical frame,
Gazebo's ENU world with FLU bodies (REP-103/105): ``A_w`` maps canonical world vectors into
the convention's world axes and ``A_b`` maps canonical body axes into its body axes. A pose
(p, R) in canonical axes becomes ``p' = A_w p`` and ``R' = A_w R A_b^T``. When both
determinants are -1 (a handedness change, as for Unity) R' is still a proper rotation, so
one 3x3 formula serves every case and no quaternion formula is written by hand per map.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from uwval.errors import FrameError
from uwval.posestream import PoseStream
from uwval.rotations import matrix_from_quat, quat_from_matrix

F64 = NDArray[np.float64]


@dataclass(frozen=True)
class Convention:
    """A pose convention: world and body axis maps from canonical ENU/FLU.

    ``world_axes`` and ``body_axes`` are 3x3 signed permutation matrices with
    ``v_convention = A @ v_canonical``.
    """

    name: str
    world_axes: F64
    body_axes: F64
    description: str

    @property
    def left_handed(self) -> bool:
        """True when the convention's axes are left-handed (det A_w = -1)."""
        return bool(np.linalg.det(self.world_axes) < 0)


def _perm(rows: list[list[int]]) -> F64:
    return np.array(rows, dtype=np.float64)


_I3 = np.eye(3)
# ROS-TCP-Connector FLU: ROS x -> Unity z, ROS y -> Unity -x, ROS z -> Unity y.
_UNITY_FROM_FLU = _perm([[0, -1, 0], [0, 0, 1], [1, 0, 0]])
# ROS-TCP-Connector ENU (compass, Unity +Z = north): east -> x, north -> z, up -> y.
_UNITY_FROM_ENU_WORLD = _perm([[1, 0, 0], [0, 0, 1], [0, 1, 0]])
# The same map under the other compass settings (GeometryCompass.UnityZAxisDirection: the
# world direction of Unity +Z), as ROS-TCP-Connector's ENU.ConvertToRUF: east, south, west.
_UNITY_FROM_ENU_COMPASS = {
    "north": _UNITY_FROM_ENU_WORLD,
    "east": _perm([[0, -1, 0], [0, 0, 1], [1, 0, 0]]),  # (-n, up, e)
    "south": _perm([[-1, 0, 0], [0, 0, 1], [0, -1, 0]]),  # (-e, up, -n)
    "west": _perm([[0, 1, 0], [0, 0, 1], [-1, 0, 0]]),  # (n, up, -e)
}
# FRD.ConvertToRUF(v) = (v.y, -v.z, v.x); NED.ConvertToRUF per compass (the world axes;
# the body stays FRD: the connector multiplies the FRD quaternion by the compass yaw)
_UNITY_FROM_FRD = _perm([[0, 1, 0], [0, 0, -1], [1, 0, 0]])
_UNITY_FROM_NED_COMPASS = {
    "east": _perm([[-1, 0, 0], [0, 0, -1], [0, 1, 0]]),
    "south": _perm([[0, -1, 0], [0, 0, -1], [-1, 0, 0]]),
    "west": _perm([[1, 0, 0], [0, 0, -1], [0, -1, 0]]),
}

#: Compass settings of ROS-TCP-Connector (the direction Unity +Z faces), in enum order.
COMPASS = ("north", "east", "south", "west")
# NED world (x north, y east, z down) and FRD body (x forward, y right, z down).
_NED_FROM_ENU = _perm([[0, 1, 0], [1, 0, 0], [0, 0, -1]])
_FRD_FROM_FLU = _perm([[1, 0, 0], [0, -1, 0], [0, 0, -1]])

CONVENTIONS: dict[str, Convention] = {
    c.name: c
    for c in (
        Convention("enu", _I3, _I3, "ROS/Gazebo: ENU world, FLU body (canonical)"),
        Convention(
            "unity-flu",
            _UNITY_FROM_FLU,
            _UNITY_FROM_FLU,
            "Unity RUF, ROS-TCP-Connector To<FLU>() map (ROS x->Unity z, y->-x, z->y)",
        ),
        Convention(
            "unity-enu",
            _UNITY_FROM_ENU_WORLD,
            _UNITY_FROM_FLU,
            "Unity RUF, ROS-TCP-Connector To<ENU>() compass map (east->x, north->z, up->y)",
        ),
        Convention("ned", _NED_FROM_ENU, _FRD_FROM_FLU, "Marine/Fossen: NED world, FRD body"),
        # ROS-TCP-Connector's FRD space (and NED with the compass north) applied to what the
        # ROS side sends, ENU/FLU from Gazebo: Unity = (v.y, -v.z, v.x) (FRD.ConvertToRUF);
        # the map a Unity scene declaring NED/FRD makes of ENU data
        Convention(
            "unity-frd",
            _UNITY_FROM_FRD,
            _UNITY_FROM_FRD,
            "Unity RUF, ROS-TCP-Connector To<FRD>() / To<NED>() (compass north) of ENU/FLU "
            "data (x->z, y->x, z->-y)",
        ),
        *(
            Convention(
                f"unity-ned-{c}",
                _UNITY_FROM_NED_COMPASS[c],
                _UNITY_FROM_FRD,
                f"Unity RUF, ROS-TCP-Connector To<NED>() with the compass set to {c}, of "
                "ENU/FLU data",
            )
            for c in ("east", "south", "west")
        ),
        *(
            Convention(
                f"unity-enu-{c}",
                _UNITY_FROM_ENU_COMPASS[c],
                _UNITY_FROM_FLU,
                f"Unity RUF, ROS-TCP-Connector To<ENU>() map with the compass set to {c} "
                "(Unity +Z faces " + c + ")",
            )
            # east is the FLU map itself (the connector applies no yaw for it): an alias
            for c in ("south", "west")
        ),
    )
}

#: Aliases accepted on the command line.
ALIASES = {
    "gazebo": "enu",
    "ros": "enu",
    "flu": "enu",
    "unity": "unity-flu",
    "frd": "ned",
    "unity-enu-north": "unity-enu",
    "unity-enu-east": "unity-flu",
    "unity-ned": "unity-frd",
    "unity-ned-north": "unity-frd",
    # ROS-TCP-Connector's RUF space takes the message's values as Unity's own: of ENU data
    # that is the canonical numbers themselves
    "unity-ruf": "enu",
}


def unity_enu_map(compass: str) -> str:
    """The name of the ``unity-enu`` convention for a ROS-TCP-Connector compass setting
    (``north`` = the default ``unity-enu``; ``east`` is ROS-TCP-Connector's FLU map itself,
    ``unity-flu``; ``south``, ``west``)."""
    c = compass.lower()
    if c not in COMPASS:
        raise FrameError(f"compass {compass!r}: choose one of {', '.join(COMPASS)}")
    return {"north": "unity-enu", "east": "unity-flu"}.get(c, f"unity-enu-{c}")


def get_convention(name: str | Convention) -> Convention:
    """Look up a convention by name (or alias); errors list the known names."""
    if isinstance(name, Convention):
        return name
    key = ALIASES.get(name.lower(), name.lower())
    try:
        return CONVENTIONS[key]
    except KeyError:
        known = ", ".join(sorted(CONVENTIONS))
        raise FrameError(f"unknown frame convention {name!r}; known: {known}") from None


def convert_arrays(
    position: F64,
    orientation: F64,
    src: str | Convention,
    dst: str | Convention,
) -> tuple[F64, F64]:
    """Convert (N, 3) positions and (N, 4) quaternions from convention ``src`` to ``dst``.

    Returns new arrays; quaternions come back with w >= 0 (q and -q are the same rotation).
    """
    mw, mb = convention_maps(src, dst)
    pos = np.asarray(position, dtype=np.float64) @ mw.T
    return np.ascontiguousarray(pos), convert_quaternions(orientation, mw, mb)


def convention_maps(src: str | Convention, dst: str | Convention) -> tuple[F64, F64]:
    """The world map and the body map (3x3 signed permutations) that take poses in
    convention ``src`` to convention ``dst`` (inverse = transpose)."""
    a = get_convention(src)
    b = get_convention(dst)
    return b.world_axes @ a.world_axes.T, b.body_axes @ a.body_axes.T


@functools.lru_cache(maxsize=256)
def _quat_map(mw_bytes: bytes, mb_bytes: bytes) -> tuple[bool, F64, F64 | None]:
    """The constants of :func:`convert_quaternions` for one pair of 3x3 maps (given as bytes, to
    be cached): whether M = mw mb^T is proper, Q = +-mb with det +1, and M's quaternion as
    a (1, 4) row (None for the identity). Computed once per convention pair (the frame
    doctor converts under every convention on each compare)."""
    mw = np.frombuffer(mw_bytes).reshape(3, 3)
    mb = np.frombuffer(mb_bytes).reshape(3, 3)
    m = mw @ mb.T
    qb = mb if np.linalg.det(mb) > 0 else -mb
    left = None if np.array_equal(m, np.eye(3)) else quat_from_matrix(m[None])[0][None, :]
    return bool(np.linalg.det(m) >= 0), qb, left


def _left_multiply(a: F64, b: F64) -> F64:
    """``quat_multiply(a[None], b)`` for one quaternion ``a`` and (N, 4) ``b``, term for term
    in the same order (equal to it to the bit), on contiguous copies of b's components (the
    general product's (1,) x (N,) broadcasts over strided columns cost ~3x)."""
    ax, ay, az, aw = (float(v) for v in a)
    bx, by, bz, bw = np.ascontiguousarray(b.T)
    out = np.empty_like(b)
    t = np.empty_like(bx)
    for j, terms in enumerate(
        (
            ((aw, bx, 1), (ax, bw, 1), (ay, bz, 1), (az, by, -1)),
            ((aw, by, 1), (ax, bz, -1), (ay, bw, 1), (az, bx, 1)),
            ((aw, bz, 1), (ax, by, 1), (ay, bx, -1), (az, bw, 1)),
            ((aw, bw, 1), (ax, bx, -1), (ay, by, -1), (az, bz, -1)),
        )
    ):
        (c0, v0, _), *rest = terms
        acc = np.multiply(c0, v0)
        for c, v, sign in rest:
            np.multiply(c, v, out=t)
            if sign > 0:
                acc += t
            else:
                acc -= t
        out[:, j] = acc
    return out


def convert_quaternions(orientation: F64, mw: F64, mb: F64) -> F64:
    """(N, 4) xyzw quaternions ``orientation`` under the world map ``mw`` and body map
    ``mb`` (3x3 signed permutations, as :func:`convert_arrays` forms them): the quaternions
    of R' = mw R mb^T, without matrices, w >= 0.

    With Q = +-mb proper (det +1) and M = mw mb^T (proper: det mw = det mb in every
    convention pair), R' = M (Q R Q^T): conjugation by Q rotates the quaternion's vector part
    (x, y, z) by Q and keeps w, then M multiplies from the left. Exact component moves and
    sign flips, no matrix round trip (3x faster; equal to it to rounding).
    """
    q = np.asarray(orientation, dtype=np.float64)
    proper, qb, left = _quat_map(mw.tobytes(), mb.tobytes())
    if not proper:  # not a pair of conventions of one handedness: general path
        return quat_from_matrix(mw @ matrix_from_quat(q) @ mb.T)
    out = np.empty_like(q)
    out[:, :3] = q[:, :3] @ qb.T
    out[:, 3] = q[:, 3]
    if left is not None:
        out = _left_multiply(left[0], out)
    # w >= 0, as quat_from_matrix returns (q and -q are one rotation): the rows with w < 0
    # negated (often none; a masked negation over all rows is several times slower)
    flip = np.flatnonzero(out[:, 3] < 0)
    if flip.size:
        out[flip] = -out[flip]
    return out


def convert_stream(stream: PoseStream, dst: str | Convention) -> PoseStream:
    """The same poses expressed in convention ``dst``."""
    conv = get_convention(dst)
    if get_convention(stream.frame).name == conv.name:
        return stream
    pos, quat = convert_arrays(stream.position, stream.orientation, stream.frame, conv)
    return stream.with_(position=pos, orientation=quat, frame=conv.name)


def unity_from_enu(stream: PoseStream, unity_map: str = "unity-flu") -> PoseStream:
    """Express an ENU/FLU (Gazebo) stream in Unity's frame using ROS-TCP-Connector's map."""
    return convert_stream(stream, unity_map)


def enu_from_unity(stream: PoseStream) -> PoseStream:
    """Express a Unity-frame stream (its ``frame`` names the map) in ENU/FLU."""
    return convert_stream(stream, "enu")


# ------------------------------------------------------------------ Unity Euler angles


def _axis_rotation(a: F64, axis: int) -> F64:
    """(N, 3, 3) right-handed rotation matrices by angles ``a`` (rad) about ``axis``."""
    c, s = np.cos(a), np.sin(a)
    i, j = [k for k in range(3) if k != axis]
    m = np.zeros((*a.shape, 3, 3))
    m[..., axis, axis] = 1
    # about y the sine terms swap sign (z x -> cyclic order z, x)
    sgn = -1.0 if axis == 1 else 1.0
    m[..., i, i], m[..., i, j], m[..., j, i], m[..., j, j] = c, -sgn * s, sgn * s, c
    return m


def quat_from_unity_euler(euler_deg: F64) -> F64:
    """Unity ``Transform.eulerAngles`` (N, 3) degrees (ex, ey, ez) -> Unity quaternions.

    Unity applies Z, then X, then Y about the fixed axes: R = Ry(ey) Rx(ex) Rz(ez).
    The quaternion is in Unity's own axes (x, y, z, w).
    """
    e = np.radians(np.asarray(euler_deg, dtype=np.float64))
    r = _axis_rotation(e[..., 1], 1) @ _axis_rotation(e[..., 0], 0) @ _axis_rotation(e[..., 2], 2)
    return quat_from_matrix(r)


def unity_euler_from_quat(q: F64) -> F64:
    """Unity quaternions -> ``Transform.eulerAngles`` (ex, ey, ez) in degrees, [0, 360)."""
    r = matrix_from_quat(q)
    # R = Ry Rx Rz: R[1,2] = -sin(ex); R[0,2] = cos ex sin ey; R[2,2] = cos ex cos ey;
    # R[1,0] = cos ex sin ez; R[1,1] = cos ex cos ez
    ex = np.arcsin(np.clip(-r[..., 1, 2], -1.0, 1.0))
    ey = np.arctan2(r[..., 0, 2], r[..., 2, 2])
    ez = np.arctan2(r[..., 1, 0], r[..., 1, 1])
    out: F64 = np.mod(np.degrees(np.stack([ex, ey, ez], axis=-1)), 360.0)
    return out
