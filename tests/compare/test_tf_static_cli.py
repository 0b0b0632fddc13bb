"""Issue 33 point 3: ``TOPIC#CHILD`` resolves through ``/tf_static`` from the command line, and
``uwval inspect`` shows the chain. The bags are written by rosbags (ROS 1 and rosbag2): a
moving odom->base_footprint on /tf, a fixed base_footprint->base_link on /tf_static, and the
base_link pose in odom composed independently (scipy) on /truth."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from cli_runner import run_uwval
from scipy.spatial.transform import Rotation

#: base_link in base_footprint (the static link): 0.3 m forward, 0.1 m up, pitched 10 deg.
STATIC_T = np.array([0.3, 0.0, 0.1])
STATIC_Q = Rotation.from_euler("xyz", [0.0, 10.0, 0.0], degrees=True).as_quat()


def _motion(n: int = 200) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Stamps (ns), positions and xyzw quaternions of base_footprint in odom (seeded)."""
    rng = np.random.default_rng(7)
    t = 1_700_000_000 * 10**9 + np.arange(n, dtype=np.int64) * 50_000_000
    s = np.arange(n) * 0.05
    pos = np.column_stack([np.cos(s), np.sin(s), 0.01 * s]) + rng.normal(0, 1e-3, (n, 3))
    yaw = s + 0.1 * np.sin(3 * s)
    quat = Rotation.from_euler("xyz", np.column_stack([0 * s, 0 * s, yaw])).as_quat()
    return t, pos, quat


def _write(path: Path, ros1: bool) -> None:
    """A bag with /tf (dynamic), /tf_static (latched once) and /truth (composed pose)."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    if ros1:  # ROS 1 Noetic's store lacks tf2_msgs: its one-line definition
        store.register(
            get_types_from_msg(
                "geometry_msgs/TransformStamped[] transforms", "tf2_msgs/msg/TFMessage"
            )
        )
    tm = store.types["tf2_msgs/msg/TFMessage"]
    ts = store.types["geometry_msgs/msg/TransformStamped"]
    ps = store.types["geometry_msgs/msg/PoseStamped"]
    hdr = store.types["std_msgs/msg/Header"]
    tim = store.types["builtin_interfaces/msg/Time"]
    vec = store.types["geometry_msgs/msg/Vector3"]
    quat = store.types["geometry_msgs/msg/Quaternion"]
    pose = store.types["geometry_msgs/msg/Pose"]
    point = store.types["geometry_msgs/msg/Point"]

    def header(stamp: int, frame: str) -> object:
        kw = {"seq": 0} if ros1 else {}
        return hdr(stamp=tim(sec=stamp // 10**9, nanosec=stamp % 10**9), frame_id=frame, **kw)

    tf_type = store.types["geometry_msgs/msg/Transform"]

    def transform(stamp: int, parent: str, child: str, p: np.ndarray, q: np.ndarray) -> object:
        return ts(
            header=header(stamp, parent),
            child_frame_id=child,
            transform=tf_type(translation=vec(x=p[0], y=p[1], z=p[2]), rotation=quat(*q)),
        )

    t, pos, q = _motion()
    world = Rotation.from_quat(q)
    truth_pos = pos + world.apply(STATIC_T)
    truth_q = (world * Rotation.from_quat(STATIC_Q)).as_quat()
    from rosbags.rosbag1 import Writer as Writer1
    from rosbags.rosbag2 import Writer as Writer2

    with Writer1(path) if ros1 else Writer2(path, version=9) as w:
        conns = {
            name: w.add_connection(name, msgtype, typestore=store)
            for name, msgtype in (
                ("/tf", "tf2_msgs/msg/TFMessage"),
                ("/tf_static", "tf2_msgs/msg/TFMessage"),
                ("/truth", "geometry_msgs/msg/PoseStamped"),
            )
        }
        ser = store.serialize_ros1 if ros1 else store.serialize_cdr
        static = tm(
            transforms=[transform(int(t[0]), "base_footprint", "base_link", STATIC_T, STATIC_Q)]
        )
        w.write(conns["/tf_static"], int(t[0]), ser(static, "tf2_msgs/msg/TFMessage"))
        for i in range(len(t)):
            stamp = int(t[i])
            msg = tm(transforms=[transform(stamp, "odom", "base_footprint", pos[i], q[i])])
            w.write(conns["/tf"], stamp, ser(msg, "tf2_msgs/msg/TFMessage"))
            truth = ps(
                header=header(stamp, "odom"),
                pose=pose(position=point(*truth_pos[i]), orientation=quat(*truth_q[i])),
            )
            w.write(conns["/truth"], stamp, ser(truth, "geometry_msgs/msg/PoseStamped"))


@pytest.fixture(params=["ros1", "rosbag2"])
def tf_bag(request: pytest.FixtureRequest, tmp_path: Path) -> Path:
    path = tmp_path / ("tf.bag" if request.param == "ros1" else "tf_bag2")
    _write(path, request.param == "ros1")
    return path


def test_a_child_under_a_static_transform_resolves_from_the_cli(tf_bag: Path) -> None:
    p = run_uwval(
        "compare", tf_bag, "--gazebo-topic", "/truth", "--unity-topic", "/tf#base_link", "--json"
    )
    assert p.returncode == 0, p.stderr
    doc = json.loads(p.stdout)
    assert doc["n_samples"] == 200
    # the chain odom->base_footprint (dynamic) * base_footprint->base_link (static) is the
    # pose composed by scipy: equal to rounding
    assert doc["position_error_norm"]["max"] < 1e-9
    assert doc["rotation_error_deg"]["max"] < 1e-6


def test_evos_bag_shape_with_a_tf_child(tf_bag: Path) -> None:
    p = run_uwval("compare", "bag", tf_bag, "/truth", "/tf#base_link", "--json")
    assert p.returncode == 0, p.stderr
    assert json.loads(p.stdout)["position_error_norm"]["max"] < 1e-9


def test_without_the_static_link_the_dynamic_child_is_offset(tf_bag: Path) -> None:
    # /tf#base_footprint is the dynamic pose itself: it differs from /truth by the static
    # link's lever arm (0.3 m forward, 0.1 m up: |(0.3, 0, 0.1)| = 0.316 m)
    p = run_uwval(
        "compare",
        tf_bag,
        "--gazebo-topic",
        "/truth",
        "--unity-topic",
        "/tf#base_footprint",
        "--json",
    )
    assert p.returncode == 0, p.stderr
    norm = json.loads(p.stdout)["position_error_norm"]
    assert norm["max"] == pytest.approx(np.hypot(0.3, 0.1), abs=1e-9)


def test_inspect_shows_the_chain(tf_bag: Path) -> None:
    p = run_uwval("inspect", tf_bag)
    assert p.returncode == 0, p.stderr
    assert (
        "/tf#base_link: odom -> base_footprint => base_link (1 static link(s) from /tf_static)"
        in p.stdout
    )
    doc = json.loads(run_uwval("inspect", tf_bag, "--json").stdout)
    assert {
        "child": "base_link",
        "chain": ["odom", "base_footprint", "base_link"],
        "static_links": 1,
    } in doc["tf_chains"]["/tf"]
