"""ROS-TCP-Connector's compass setting for the ENU map (issue 18): uwval's unity-enu-<compass>
conventions against the connector's GeometryCompass / CoordinateSpaces formulas
(ENU.ConvertFromRUF for vectors; for quaternions Quaternion.Euler(0, a, 0) * q with
a = -90 (north), 0 (east), 90 (south), 180 (west) deg, then the FLU quaternion map)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from cli_runner import run_uwval

from uwval.errors import FrameError
from uwval.frames import COMPASS, convert_arrays, get_convention, unity_enu_map
from uwval.io import read_stream

# ENU.ConvertFromRUF(Vector3 v) per compass: Unity (x, y, z) -> ENU
FROM_RUF = {
    "north": lambda v: np.stack([v[:, 0], v[:, 2], v[:, 1]], axis=1),
    "east": lambda v: np.stack([v[:, 2], -v[:, 0], v[:, 1]], axis=1),
    "south": lambda v: np.stack([-v[:, 0], -v[:, 2], v[:, 1]], axis=1),
    "west": lambda v: np.stack([-v[:, 2], v[:, 0], v[:, 1]], axis=1),
}
YAW_DEG = {"north": -90.0, "east": 0.0, "south": 90.0, "west": 180.0}


def hamilton(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a * b for (x, y, z, w) quaternions (Unity's Quaternion operator *)."""
    ax, ay, az, aw = a.T
    bx, by, bz, bw = b.T
    return np.stack(
        [
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
            aw * bw - ax * bx - ay * by - az * bz,
        ],
        axis=1,
    )


def connector_quat_from_ruf(q: np.ndarray, compass: str) -> np.ndarray:
    half = math.radians(YAW_DEG[compass]) / 2
    yaw = np.tile([0.0, math.sin(half), 0.0, math.cos(half)], (len(q), 1))  # Euler(0, a, 0)
    r = hamilton(yaw, q)
    return np.stack([r[:, 2], -r[:, 0], r[:, 1], -r[:, 3]], axis=1)  # FLU: (z, -x, y, -w)


@pytest.mark.parametrize("compass", COMPASS)
def test_compass_maps_match_ros_tcp_connector(compass: str) -> None:
    rng = np.random.default_rng(18)
    pos_u = rng.normal(size=(200, 3)) * 50
    q_u = rng.normal(size=(200, 4))
    q_u /= np.linalg.norm(q_u, axis=1, keepdims=True)
    pos, quat = convert_arrays(pos_u, q_u, unity_enu_map(compass), "enu")
    np.testing.assert_allclose(pos, FROM_RUF[compass](pos_u), atol=1e-12)
    ref = connector_quat_from_ruf(q_u, compass)
    dots = np.abs(np.sum(quat * ref, axis=1))  # q and -q are one rotation
    np.testing.assert_allclose(dots, 1.0, atol=1e-12)
    # and back: ENU -> Unity under the same compass
    back_p, back_q = convert_arrays(pos, quat, "enu", unity_enu_map(compass))
    np.testing.assert_allclose(back_p, pos_u, atol=1e-12)
    np.testing.assert_allclose(np.abs(np.sum(back_q * q_u, axis=1)), 1.0, atol=1e-12)


def test_a_unity_identity_faces_the_compass_direction() -> None:
    ident = np.array([[0.0, 0.0, 0.0, 1.0]])
    # Unity +Z (an object's forward) faces the compass direction: ENU yaw of that heading
    for compass, yaw in (("north", 90.0), ("east", 0.0), ("south", -90.0), ("west", 180.0)):
        _, q = convert_arrays(np.zeros((1, 3)), ident, unity_enu_map(compass), "enu")
        x, y, z, w = q[0]
        got = math.degrees(math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z)))
        assert abs((got - yaw + 180) % 360 - 180) < 1e-9, compass
    with pytest.raises(FrameError, match="compass 'up'"):
        unity_enu_map("up")
    # compass east is the connector's FLU map itself (no yaw): one convention, two names
    assert unity_enu_map("east") == "unity-flu"
    assert get_convention("unity-enu-east").name == "unity-flu"


def test_simulate_with_a_compass_map_round_trips(tmp_path: Path) -> None:
    log = tmp_path / "w.mcap"
    res = run_uwval(
        "simulate", "--force", "10,0,0", "--torque", "0,0,1", "--duration", "1",
        "--unity-map", "unity-enu-west", "--transport", "ideal", "--frame-model", "fixed",
        "--no-float32", "-o", log,
    )  # fmt: skip
    assert res.returncode == 0, res.stderr
    u = read_stream(log, "/unity/model_rov_pose")
    g = read_stream(log, "/gazebo/model_rov_pose")
    assert u.frame == "unity-enu-west"
    idx = np.searchsorted(g.t, u.applied_stamp)
    pos, _ = convert_arrays(u.position, u.orientation, u.frame, "enu")
    np.testing.assert_allclose(pos, g.position[idx], atol=1e-12)
    # west: Unity +Z faces west, so a vehicle moving east has a decreasing Unity z
    assert u.position[-1, 2] < u.position[0, 2] - 0.01


# NED.ConvertToRUF(Vector3 v) per compass (FRD.ConvertToRUF is the north case), and the
# quaternion: Quaternion(q.y, -q.z, q.x, -q.w), then multiplied by the compass yaw
NED_TO_RUF = {
    "north": lambda v: np.stack([v[:, 1], -v[:, 2], v[:, 0]], axis=1),
    "east": lambda v: np.stack([-v[:, 0], -v[:, 2], v[:, 1]], axis=1),
    "south": lambda v: np.stack([-v[:, 1], -v[:, 2], -v[:, 0]], axis=1),
    "west": lambda v: np.stack([v[:, 0], -v[:, 2], -v[:, 1]], axis=1),
}
# GeometryCompass.k_NegativeNinetyYaw / k_OneEightyYaw / k_NinetyYaw: Euler(0, a, 0)
NED_YAW_DEG = {"north": 0.0, "east": -90.0, "south": 180.0, "west": 90.0}


@pytest.mark.parametrize("compass", COMPASS)
def test_ned_and_frd_maps_match_ros_tcp_connector(compass: str) -> None:
    """What a Unity scene declaring NED (or FRD, = NED north) makes of the ENU/FLU values the
    Gazebo side sends: uwval's unity-ned-<compass> / unity-frd against CoordinateSpaces.cs."""
    rng = np.random.default_rng(19)
    v = rng.normal(size=(200, 3)) * 50
    q = rng.normal(size=(200, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    name = "unity-frd" if compass == "north" else f"unity-ned-{compass}"
    pos_u, quat_u = convert_arrays(v, q, "enu", name)
    np.testing.assert_allclose(pos_u, NED_TO_RUF[compass](v), atol=1e-12)
    half = math.radians(NED_YAW_DEG[compass]) / 2
    yaw = np.tile([0.0, math.sin(half), 0.0, math.cos(half)], (len(q), 1))
    ref = hamilton(yaw, np.stack([q[:, 1], -q[:, 2], q[:, 0], -q[:, 3]], axis=1))
    np.testing.assert_allclose(np.abs(np.sum(quat_u * ref, axis=1)), 1.0, atol=1e-12)
    assert get_convention(f"unity-ned-{compass}").name == name


def test_ruf_takes_the_values_as_unitys_own() -> None:
    rng = np.random.default_rng(20)
    v = rng.normal(size=(10, 3))
    q = rng.normal(size=(10, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    pos_u, quat_u = convert_arrays(v, q, "enu", "unity-ruf")  # RUF: ConvertToRUF is identity
    np.testing.assert_array_equal(pos_u, v)
    np.testing.assert_allclose(np.abs(np.sum(quat_u * q, axis=1)), 1.0, atol=1e-15)


@pytest.mark.parametrize("unity_map", ["unity-frd", "unity-ned-west", "unity-ruf"])
def test_simulate_renders_with_the_ned_frd_and_ruf_maps(tmp_path: Path, unity_map: str) -> None:
    log = tmp_path / "r.mcap"
    run_uwval(
        "simulate", "--duration", "2", "--force", "20,5,0", "--torque", "0,0,1",
        "--unity-map", unity_map, "--transport", "ideal", "--frame-model", "fixed",
        "--no-float32", "--unity-clock-drift", "0", "-o", log, check=True,
    )  # fmt: skip
    u = read_stream(log, "/unity/model_rov_pose")
    assert u.frame == get_convention(unity_map).name
    out = run_uwval("compare", log, "--sync", "nearest", "--json")
    assert out.returncode == 0, out.stderr
    import json

    doc = json.loads(out.stdout)
    assert doc["frame"]["configured"] == get_convention(unity_map).name
    assert doc["position_error_norm"]["max"] < 0.05  # hold lag only: the map round-trips


def test_direct_quaternion_maps_equal_the_matrix_round_trip() -> None:
    """convert_arrays moves and signs quaternion components directly (no matrices): equal to
    R' = A_w R A_b^T through rotation matrices, for every pair of conventions."""
    from uwval.frames import CONVENTIONS
    from uwval.rotations import matrix_from_quat, quat_from_matrix

    rng = np.random.default_rng(21)
    q = rng.normal(size=(2000, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    p = rng.normal(size=(2000, 3))
    for a in CONVENTIONS.values():
        for b in CONVENTIONS.values():
            mw = b.world_axes @ a.world_axes.T
            mb = b.body_axes @ a.body_axes.T
            ref = quat_from_matrix(mw @ matrix_from_quat(q) @ mb.T)
            _, got = convert_arrays(p, q, a, b)
            np.testing.assert_allclose(got, ref, atol=1e-15, err_msg=f"{a.name}->{b.name}")
            assert (got[:, 3] >= 0).all()
