"""Writing logs: every format read back by rosbags, the mcap library and ROS 1's rosbag;
bulk encode == rosbags serialization; fast decode == rosbags decode on generated messages."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from uwval.errors import LogWriteError
from uwval.io import open_writer, read_stream, write_stream
from uwval.io.decode import decode_poses
from uwval.io.encode import encode_header, encode_pose_stamped
from uwval.io.raw import TopicBuilder
from uwval.io.ros import header_msg, pose_stamped, typestore
from uwval.posestream import PoseStream

TOPIC = "/unity/model_rov_pose"


def _stream(n: int = 500, seed: int = 1) -> PoseStream:
    rng = np.random.default_rng(seed)
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1)[:, None]
    return PoseStream.from_arrays(
        np.arange(n, dtype=np.int64) * 16_666_667 + 1_700_000_000 * 10**9,
        rng.normal(size=(n, 3)) * 5,
        q,
        applied_stamp=np.arange(n, dtype=np.int64) * 10**7,
    )


FORMATS = [
    ("mcap", "log.mcap"),
    ("rosbag2", "log_sqlite"),
    ("rosbag2-mcap", "log_mcap"),
    ("rosbag1", "log.bag"),
]


def _write(path: Path, fmt: str, s: PoseStream) -> None:
    with open_writer(path, fmt, metadata={"run": "r1"}) as w:
        write_stream(w, TOPIC, s, "unity-flu")
        for i in range(3):  # the incremental API, as the bridge's recorder uses it
            w.write_pose(
                "/gazebo/model_rov_pose",
                10**9 * (i + 1),
                np.array([i, 0, 0.0]),
                np.array([0, 0, 0, 1.0]),
                "world",
                log_time=10**9 * (i + 1) + 5,
            )
            w.write_header("/gazebo/model_rov_pose/applied_stamp", 7 * i, 10**9 * (i + 1) + 5)
        w.flush()


@pytest.mark.parametrize(("fmt", "name"), FORMATS)
def test_written_logs_read_back_by_uwval_and_rosbags(tmp_path: Path, fmt: str, name: str) -> None:
    s = _stream()
    path = tmp_path / name
    _write(path, fmt, s)
    r = read_stream(path, TOPIC)
    assert r.frame == "unity-flu"  # taken from header.frame_id
    np.testing.assert_array_equal(r.t, s.t)
    np.testing.assert_array_equal(r.position, s.position)
    np.testing.assert_array_equal(r.orientation, s.orientation)
    assert r.applied_stamp is not None
    np.testing.assert_array_equal(r.applied_stamp, s.applied_stamp)
    g = read_stream(path, "gazebo/model_rov_pose")
    np.testing.assert_array_equal(g.applied_stamp, [0, 7, 14])
    assert g.frame == "enu"

    from rosbags.highlevel import AnyReader

    with AnyReader([path]) as reader:
        conns = [c for c in reader.connections if c.topic == TOPIC]
        got: list[Any] = [
            reader.deserialize(d, c.msgtype) for c, _, d in reader.messages(connections=conns)
        ]
    assert len(got) == len(s)
    assert got[7].header.frame_id == "unity-flu"
    p = got[7].pose.position
    assert (p.x, p.y, p.z) == tuple(s.position[7])
    assert got[7].header.stamp.sec * 10**9 + got[7].header.stamp.nanosec == s.t[7]


@pytest.mark.parametrize(("fmt", "name"), [("mcap", "log.mcap"), ("rosbag2-mcap", "log_mcap")])
def test_written_mcap_read_by_mcap_library(tmp_path: Path, fmt: str, name: str) -> None:
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    s = _stream(200)
    path = tmp_path / name
    _write(path, fmt, s)
    file = path if path.is_file() else next(path.glob("*.mcap"))
    with open(file, "rb") as fh:
        reader = make_reader(fh, decoder_factories=[DecoderFactory()])
        msgs = [m for _s, _c, _m, m in reader.iter_decoded_messages(topics=[TOPIC])]
        summary = reader.get_summary()
    assert len(msgs) == 200
    assert summary is not None
    assert summary.statistics is not None
    o = msgs[-1].pose.orientation
    assert (o.x, o.y, o.z, o.w) == tuple(s.orientation[-1])
    if fmt == "mcap":
        with open(file, "rb") as fh:
            meta = {m.name: m.metadata for m in make_reader(fh).iter_metadata()}
        assert meta["uwval"] == {"run": "r1"}


def _ros1_available() -> bool:
    try:
        return (
            subprocess.run(
                ["/usr/bin/python3", "-c", "import rosbag"], capture_output=True, timeout=60
            ).returncode
            == 0
        )
    except (OSError, subprocess.TimeoutExpired):
        return False


ROS1_READER = """
import json, sys, rosbag
bag = rosbag.Bag(sys.argv[1])
out = {"count": bag.get_message_count(), "topics": {}}
for topic, info in bag.get_type_and_topic_info().topics.items():
    out["topics"][topic] = [info.msg_type, info.message_count]
rows = []
for topic, msg, t in bag.read_messages(topics=[sys.argv[2]]):
    p, o = msg.pose.position, msg.pose.orientation
    rows.append([msg.header.stamp.to_nsec(), msg.header.frame_id, p.x, p.y, p.z,
                 o.x, o.y, o.z, o.w, t.to_nsec()])
out["rows"] = rows
print(json.dumps(out))
"""


@pytest.mark.skipif(not _ros1_available(), reason="ROS 1 rosbag (python3-rosbag) not installed")
def test_ros1_bag_read_by_ros1_rosbag(tmp_path: Path) -> None:
    s = _stream(300)
    path = tmp_path / "log.bag"
    _write(path, "rosbag1", s)
    proc = subprocess.run(
        ["/usr/bin/python3", "-c", ROS1_READER, str(path), TOPIC],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 0, proc.stderr
    out = json.loads(proc.stdout)
    assert out["topics"][TOPIC] == ["geometry_msgs/PoseStamped", 300]
    assert out["topics"]["/gazebo/model_rov_pose/applied_stamp"] == ["std_msgs/Header", 3]
    rows = out["rows"]
    assert [r[0] for r in rows] == s.t.tolist()
    assert [r[9] for r in rows] == s.t.tolist()
    assert {r[1] for r in rows} == {"unity-flu"}
    np.testing.assert_array_equal(np.array([r[2:5] for r in rows]), s.position)
    np.testing.assert_array_equal(np.array([r[5:9] for r in rows]), s.orientation)


def test_open_writer_errors(tmp_path: Path) -> None:
    with pytest.raises(LogWriteError, match="unknown log format 'zip'"):
        open_writer(tmp_path / "x", "zip")
    (tmp_path / "exists").mkdir()
    (tmp_path / "exists" / "notes.txt").write_text("not a bag")
    with pytest.raises(LogWriteError, match="exists"):
        open_writer(tmp_path / "exists", "rosbag2")
    assert (tmp_path / "exists" / "notes.txt").exists()


@pytest.mark.parametrize(("fmt", "name"), FORMATS)
def test_rewriting_a_log_replaces_the_old_one(tmp_path: Path, fmt: str, name: str) -> None:
    path = tmp_path / name
    _write(path, fmt, _stream(50))
    _write(path, fmt, _stream(20, seed=9))
    r = read_stream(path, TOPIC)
    np.testing.assert_array_equal(r.position, _stream(20, seed=9).position)
    with pytest.raises(LogWriteError, match="cannot open"):
        open_writer(tmp_path / "no" / "such" / "dir.mcap", "mcap")


frame_ids = st.text(alphabet=st.characters(min_codepoint=33, max_codepoint=126), max_size=12)
finite = st.floats(allow_nan=False, allow_infinity=False, width=64)


@settings(max_examples=40, deadline=None)
@given(
    fid=frame_ids,
    t=st.integers(0, 2**31 * 10**9 - 1),
    vals=st.lists(finite, min_size=7, max_size=7),
)
def test_bulk_encode_equals_rosbags_serialization(fid: str, t: int, vals: list[float]) -> None:
    pos = np.array([vals[:3]])
    q = np.array([vals[3:]])
    for enc, ros in (("cdr", 2), ("ros1", 1)):
        store = typestore(ros)
        ser = store.serialize_cdr if ros == 2 else store.serialize_ros1
        ref = bytes(ser(pose_stamped(t, pos[0], q[0], fid, ros), "geometry_msgs/msg/PoseStamped"))
        assert encode_pose_stamped([t], pos, q, fid, enc)[0].tobytes() == ref
        ref_h = bytes(ser(header_msg(t, fid, ros), "std_msgs/msg/Header"))
        assert encode_header([t], fid, enc)[0].tobytes() == ref_h


def _msgs(
    store: Any, msgtype: str, rng: np.random.Generator, frames: list[str], children: list[str]
) -> list[Any]:
    T = store.types
    out = []
    for i, (fid, child) in enumerate(zip(frames, children, strict=True)):
        v = rng.normal(size=7)
        has_seq = "seq" in T["std_msgs/msg/Header"].__dataclass_fields__
        kw: dict[str, Any] = {"seq": i} if has_seq else {}
        hdr = T["std_msgs/msg/Header"](
            stamp=T["builtin_interfaces/msg/Time"](sec=1000 + i, nanosec=i * 7), frame_id=fid, **kw
        )
        pt = T["geometry_msgs/msg/Point"](x=v[0], y=v[1], z=v[2])
        qt = T["geometry_msgs/msg/Quaternion"](x=v[3], y=v[4], z=v[5], w=v[6])
        pose = T["geometry_msgs/msg/Pose"](position=pt, orientation=qt)
        cov = rng.normal(size=36)
        pwc = T["geometry_msgs/msg/PoseWithCovariance"](pose=pose, covariance=cov)
        if msgtype == "geometry_msgs/msg/PoseStamped":
            m = T[msgtype](header=hdr, pose=pose)
        elif msgtype == "geometry_msgs/msg/Pose":
            m = pose
        elif msgtype == "geometry_msgs/msg/PoseWithCovarianceStamped":
            m = T[msgtype](header=hdr, pose=pwc)
        elif msgtype == "geometry_msgs/msg/TransformStamped":
            tr = T["geometry_msgs/msg/Transform"](
                translation=T["geometry_msgs/msg/Vector3"](x=v[0], y=v[1], z=v[2]), rotation=qt
            )
            m = T[msgtype](header=hdr, child_frame_id=child, transform=tr)
        else:
            tw = T["geometry_msgs/msg/Twist"](
                linear=T["geometry_msgs/msg/Vector3"](x=1.0, y=2.0, z=3.0),
                angular=T["geometry_msgs/msg/Vector3"](x=4.0, y=5.0, z=6.0),
            )
            twc = T["geometry_msgs/msg/TwistWithCovariance"](twist=tw, covariance=cov)
            m = T[msgtype](header=hdr, child_frame_id=child, pose=pwc, twist=twc)
        out.append(m)
    return out


@settings(max_examples=25, deadline=None)
@given(
    msgtype=st.sampled_from(
        [
            "geometry_msgs/msg/PoseStamped",
            "geometry_msgs/msg/Pose",
            "geometry_msgs/msg/PoseWithCovarianceStamped",
            "geometry_msgs/msg/TransformStamped",
            "nav_msgs/msg/Odometry",
        ]
    ),
    ros=st.sampled_from([1, 2]),
    frames=st.lists(frame_ids, min_size=1, max_size=6),
    seed=st.integers(0, 2**16),
)
def test_fast_decode_equals_rosbags_on_mixed_layouts(
    msgtype: str, ros: int, frames: list[str], seed: int
) -> None:
    """Mixed frame_id / child_frame_id lengths in one topic: fast path == per-message path."""
    rng = np.random.default_rng(seed)
    store = typestore(ros)
    children = [f[::-1] + "c" * (i % 3) for i, f in enumerate(frames)]
    msgs = _msgs(store, msgtype, rng, frames, children)
    ser = store.serialize_cdr if ros == 2 else store.serialize_ros1
    b = TopicBuilder("/t", msgtype, "cdr" if ros == 2 else "ros1")
    b.add_payloads([bytes(ser(m, msgtype)) for m in msgs], list(range(len(msgs))))
    raw = b.build()
    fast = decode_poses(raw)
    slow = decode_poses(raw, fast=False)
    assert fast.handled.all()
    np.testing.assert_array_equal(fast.stamp, slow.stamp)
    assert np.array_equal(fast.pose.view(np.uint64), slow.pose.view(np.uint64))
    assert [fast.names[c] if c >= 0 else None for c in fast.frame_code] == [
        slow.names[c] if c >= 0 else None for c in slow.frame_code
    ]
    assert [fast.names[c] if c >= 0 else None for c in fast.child_code] == [
        slow.names[c] if c >= 0 else None for c in slow.child_code
    ]


def test_fast_path_leaves_odd_payloads_to_rosbags() -> None:
    """Big-endian CDR is not the fast layout: it is decoded per message, same values."""
    store = typestore(2)
    msg = pose_stamped(123_000_000_007, np.array([1.0, 2, 3]), np.array([0, 0, 0, 1.0]), "w")
    le = bytes(store.serialize_cdr(msg, "geometry_msgs/msg/PoseStamped"))
    be = bytes(store.serialize_cdr(msg, "geometry_msgs/msg/PoseStamped", little_endian=False))
    b = TopicBuilder("/t", "geometry_msgs/msg/PoseStamped", "cdr")
    b.add_payloads([le, be, le[:-3]], [1, 2, 3])
    raw = b.build()
    from uwval.io.fastdecode import fast_decode

    fast = fast_decode(raw.msgtype, raw.encoding, raw.buf, raw.offset, raw.length)
    assert fast.handled.tolist() == [True, False, False]
    raw2 = TopicBuilder("/t", "geometry_msgs/msg/PoseStamped", "cdr")
    raw2.add_payloads([le, be], [1, 2])
    dec = decode_poses(raw2.build())
    np.testing.assert_array_equal(dec.pose[0], dec.pose[1])
    assert dec.stamp.tolist() == [123_000_000_007] * 2


@pytest.mark.parametrize("mode", ["FILE", "MESSAGE"])
def test_rosbag2_zstd_compressed_bags_read(tmp_path: Path, mode: str) -> None:
    """rosbag2 sqlite3 bags with zstd file or message compression (written by rosbags)."""
    from rosbags.rosbag2 import Writer
    from rosbags.rosbag2.enums import CompressionFormat, CompressionMode

    s = _stream(120)
    path = tmp_path / f"z_{mode.lower()}"
    store = typestore(2)
    w = Writer(path, version=9)
    w.set_compression(CompressionMode[mode], CompressionFormat.ZSTD)
    with w:
        conn = w.add_connection(TOPIC, "geometry_msgs/msg/PoseStamped", typestore=store)
        rows = encode_pose_stamped(s.t, s.position, s.orientation, "world")
        for i in range(len(s)):
            w.write(conn, int(s.t[i]), rows[i].tobytes())
    r = read_stream(path, TOPIC)
    np.testing.assert_array_equal(r.position, s.position)
    np.testing.assert_array_equal(r.t, s.t)


def test_pose_without_header_is_stamped_with_log_time(tmp_path: Path) -> None:
    store = typestore(2)
    T = store.types
    path = tmp_path / "pose.mcap"
    with open_writer(path) as w:
        for i in range(10):
            m = T["geometry_msgs/msg/Pose"](
                position=T["geometry_msgs/msg/Point"](x=float(i), y=0.0, z=0.0),
                orientation=T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
            )
            w.write_raw(
                "/pose_only",
                "geometry_msgs/msg/Pose",
                bytes(store.serialize_cdr(m, "geometry_msgs/msg/Pose")),
                10**9 + i * 10**8,
            )
    s = read_stream(path, "pose_only")
    np.testing.assert_array_equal(s.t, 10**9 + np.arange(10) * 10**8)
    np.testing.assert_array_equal(s.position[:, 0], np.arange(10.0))


def test_killed_rosbag2_sqlite_recording_is_readable_after_flush(tmp_path: Path) -> None:
    """flush() commits; a copy of the directory taken before close() (no metadata.yaml)."""
    import shutil

    s = _stream(80)
    path = tmp_path / "rec"
    w = open_writer(path, "rosbag2")
    write_stream(w, TOPIC, s, "world")
    w.flush()
    snap = tmp_path / "snap"
    shutil.copytree(path, snap)
    w.close()
    assert not (snap / "metadata.yaml").exists()
    r = read_stream(snap, TOPIC)
    np.testing.assert_array_equal(r.position, s.position)
