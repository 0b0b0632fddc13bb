"""Frame conventions (DESIGN.md section 3): closed-form facts and property-based round trips."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from uwval.errors import FrameError
from uwval.frames import (
    CONVENTIONS,
    convert_arrays,
    get_convention,
    quat_from_unity_euler,
    unity_euler_from_quat,
)
from uwval.rotations import (
    geodesic_angle,
    matrix_from_quat,
    quat_from_matrix,
    quat_from_rpy,
    rpy_from_quat,
    wrap_deg,
)

finite = st.floats(-1e3, 1e3, allow_nan=False, allow_infinity=False)


def unit_quats(n: int) -> st.SearchStrategy[np.ndarray]:
    return (
        arrays(np.float64, (n, 4), elements=st.floats(-1, 1))
        .filter(lambda a: bool(np.all(np.linalg.norm(a, axis=1) > 0.1)))
        .map(lambda a: a / np.linalg.norm(a, axis=1, keepdims=True))
    )


def same_rotation(a: np.ndarray, b: np.ndarray, tol: float = 1e-9) -> bool:
    return bool(np.all(geodesic_angle(a, b) < tol))


@settings(max_examples=100, deadline=None)
@given(quat_a=unit_quats(20), quat_b=unit_quats(20), scale=st.floats(0.5, 2.0))
def test_geodesic_angle_equals_scipy_and_ignores_sign_and_scale(
    quat_a: np.ndarray, quat_b: np.ndarray, scale: float
) -> None:
    from scipy.spatial.transform import Rotation

    want = (Rotation.from_quat(quat_b).inv() * Rotation.from_quat(quat_a)).magnitude()
    np.testing.assert_allclose(geodesic_angle(quat_a, quat_b), want, rtol=0, atol=1e-12)
    np.testing.assert_allclose(geodesic_angle(-scale * quat_a, quat_b), want, rtol=0, atol=1e-12)


def test_geodesic_angle_is_exact_near_zero() -> None:
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(3)
    base = Rotation.random(500, random_state=4)
    rotvec = rng.normal(size=(500, 3)) * 1e-7  # ~0.1 microradian apart
    turned = (base * Rotation.from_rotvec(rotvec)).as_quat()
    got = geodesic_angle(turned, base.as_quat())
    np.testing.assert_allclose(got, np.linalg.norm(rotvec, axis=1), rtol=1e-6)
    # text logs keep 9 decimals: |q| = 1 +- 1e-9; equal orientations are still 0, not 0.005 deg
    q = np.round(base.as_quat(), 9)
    assert geodesic_angle(q, q).max() == 0.0
    assert geodesic_angle(q, -q).max() == 0.0


@settings(max_examples=60, deadline=None)
@given(
    pos=arrays(np.float64, (5, 3), elements=finite),
    quat=unit_quats(5),
    src=st.sampled_from(sorted(CONVENTIONS)),
    dst=st.sampled_from(sorted(CONVENTIONS)),
)
def test_round_trip_any_pair(pos: np.ndarray, quat: np.ndarray, src: str, dst: str) -> None:
    p2, q2 = convert_arrays(pos, quat, src, dst)
    p3, q3 = convert_arrays(p2, q2, dst, src)
    np.testing.assert_allclose(p3, pos, atol=1e-9)
    assert same_rotation(q3, quat)
    # converted rotations stay proper rotations (det +1) even across a handedness change
    np.testing.assert_allclose(np.linalg.det(matrix_from_quat(q2)), 1.0, atol=1e-9)


def test_unity_identity_is_enu_yaw_plus_90_under_enu_map() -> None:
    ident = np.array([[0.0, 0.0, 0.0, 1.0]])
    _, q_enu = convert_arrays(np.zeros((1, 3)), ident, "unity-enu", "enu")
    rpy = np.degrees(rpy_from_quat(q_enu))[0]
    np.testing.assert_allclose(rpy, [0.0, 0.0, 90.0], atol=1e-9)


def test_unity_identity_is_ros_identity_under_flu_map() -> None:
    ident = np.array([[0.0, 0.0, 0.0, 1.0]])
    _, q = convert_arrays(np.zeros((1, 3)), ident, "unity-flu", "enu")
    assert same_rotation(q, ident)


def test_flu_map_vectors_match_ros_tcp_connector() -> None:
    # Vector Unity -> ROS (FLU): (x, y, z)_ros = (z_u, -x_u, y_u)
    u = np.array([[1.0, 2.0, 3.0]])
    p, _ = convert_arrays(u, np.array([[0, 0, 0, 1.0]]), "unity-flu", "enu")
    np.testing.assert_allclose(p, [[3.0, -1.0, 2.0]])
    # Vector Unity -> ENU (compass): (x_u, z_u, y_u)
    p, _ = convert_arrays(u, np.array([[0, 0, 0, 1.0]]), "unity-enu", "enu")
    np.testing.assert_allclose(p, [[1.0, 3.0, 2.0]])
    # Unity -> NED: (z_u, x_u, -y_u); ENU (1,3,2) -> NED (3,1,-2)
    p_ned, _ = convert_arrays(p, np.array([[0, 0, 0, 1.0]]), "enu", "ned")
    np.testing.assert_allclose(p_ned, [[3.0, 1.0, -2.0]])


@settings(max_examples=60, deadline=None)
@given(q=unit_quats(3))
def test_flu_quaternion_formula_matches_connector(q: np.ndarray) -> None:
    # ROS-TCP-Connector: quaternion Unity -> ROS FLU is (qz, -qx, qy, -qw)
    _, q_ros = convert_arrays(np.zeros((3, 3)), q, "unity-flu", "enu")
    expected = np.stack([q[:, 2], -q[:, 0], q[:, 1], -q[:, 3]], axis=1)
    assert same_rotation(q_ros, expected)


@settings(max_examples=60, deadline=None)
@given(e=arrays(np.float64, (4, 3), elements=st.floats(0, 359.9)))
def test_unity_euler_to_ros_rpy(e: np.ndarray) -> None:
    # keep away from gimbal lock (pitch = ex near +-90 deg)
    e[:, 0] = np.where(np.abs(wrap_deg(e[:, 0])) > 80, 30.0, e[:, 0])
    q_unity = quat_from_unity_euler(e)
    _, q_ros = convert_arrays(np.zeros((4, 3)), q_unity, "unity-flu", "enu")
    rpy = np.degrees(rpy_from_quat(q_ros))
    expected = np.stack([-e[:, 2], e[:, 0], -e[:, 1]], axis=1)
    np.testing.assert_allclose(wrap_deg(rpy - expected), 0.0, atol=1e-7)


@settings(max_examples=60, deadline=None)
@given(e=arrays(np.float64, (4, 3), elements=st.floats(0, 359.9)))
def test_unity_euler_round_trip(e: np.ndarray) -> None:
    e[:, 0] = np.where(np.abs(wrap_deg(e[:, 0])) > 80, 10.0, e[:, 0])
    back = unity_euler_from_quat(quat_from_unity_euler(e))
    np.testing.assert_allclose(wrap_deg(back - e), 0.0, atol=1e-7)


def test_unity_euler_matches_scipy_zxy() -> None:
    from scipy.spatial.transform import Rotation

    e = np.array([[10.0, 20.0, 30.0], [350.0, 45.0, 120.0]])
    # Unity: Z, then X, then Y about the fixed axes == extrinsic "zxy" with angles (ez, ex, ey)
    ref = Rotation.from_euler("zxy", np.stack([e[:, 2], e[:, 0], e[:, 1]], 1), degrees=True)
    assert same_rotation(quat_from_unity_euler(e), ref.as_quat())


@settings(max_examples=80, deadline=None)
@given(q=unit_quats(6))
def test_quaternion_matrix_round_trip(q: np.ndarray) -> None:
    assert same_rotation(quat_from_matrix(matrix_from_quat(q)), q)


def test_rpy_matches_scipy() -> None:
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(1)
    q = Rotation.random(50, random_state=rng).as_quat()
    np.testing.assert_allclose(rpy_from_quat(q), Rotation.from_quat(q).as_euler("xyz"), atol=1e-9)
    assert same_rotation(quat_from_rpy(rpy_from_quat(q)), q)


def test_wrap_deg_359_vs_1_is_2_degrees() -> None:
    assert wrap_deg(np.array([359.0 - 1.0]))[0] == pytest.approx(-2.0)
    assert wrap_deg(np.array([1.0 - 359.0]))[0] == pytest.approx(2.0)
    assert wrap_deg(np.array([-180.0]))[0] == 180.0


def test_ned_yaw_relation() -> None:
    # psi_NED = pi/2 - psi_ENU for a level vehicle; theta_NED = -theta_ENU; phi_NED = phi_ENU
    rpy_enu = np.radians([[5.0, 10.0, 30.0]])
    _, q_ned = convert_arrays(np.zeros((1, 3)), quat_from_rpy(rpy_enu), "enu", "ned")
    rpy_ned = np.degrees(rpy_from_quat(q_ned))[0]
    np.testing.assert_allclose(wrap_deg(rpy_ned - [5.0, -10.0, 60.0]), 0.0, atol=1e-9)


def test_unknown_convention_lists_known() -> None:
    with pytest.raises(FrameError, match="unity-flu"):
        get_convention("unity-xyz")
