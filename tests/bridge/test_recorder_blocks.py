"""The recorder's block write path (issue 15): blocks of PoseStamped / Header encoded with numpy
and written at once give exactly the messages the per-message path gives, in every format that
``uwval simulate`` writes, read back by the field's own libraries (mcap + mcap_ros2's decoder,
rosbags' AnyReader)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
from per_message import PerMessage
from reference_writers import McapLibraryWriter

from uwval.bridge.recorder import BridgeRecorder, open_log_writer, scan_mcap
from uwval.errors import LogWriteError
from uwval.io import read_stream
from uwval.io.encode import encode_header as encode_header_block
from uwval.io.encode import encode_pose_stamped as encode_pose_block
from uwval.io.mcap_io import McapPoseWriter
from uwval.io.ros import HEADER, POSE_STAMPED, header_msg, pose_stamped, typestore
from uwval.io.writers import Rosbag1PoseWriter

FORMATS = ["mcap", "rosbag2", "rosbag2-mcap", "rosbag1"]
SUFFIX = {"mcap": ".mcap", "rosbag2": "", "rosbag2-mcap": "", "rosbag1": ".bag"}


def poses(n: int, seed: int = 1) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Stamps (ns, some with nanoseconds near 1e9), positions (m) and unit quaternions."""
    rng = np.random.default_rng(seed)
    t = np.cumsum(rng.integers(1, 40_000_000, n)).astype(np.int64) + 999_999_990
    pos = rng.normal(0.0, 300.0, (n, 3))
    q = rng.normal(size=(n, 4))
    return t, pos, q / np.linalg.norm(q, axis=1, keepdims=True)


@pytest.mark.parametrize(
    "frame_id", ["", "w", "ab", "abc", "ÿé", "world", "abcdef", "unity-flu", "unity-ned-south"]
)
@pytest.mark.parametrize("encoding", ["cdr", "ros1"])
def test_blocks_are_rosbags_bytes(frame_id: str, encoding: str) -> None:
    """Every row equals rosbags' serializer of that message (frame_id lengths 0-15 cover
    every CDR padding before the doubles; non-ASCII frame ids count bytes, not chars)."""
    t, pos, q = poses(40)
    ros = 1 if encoding == "ros1" else 2
    ts = typestore(ros)
    ser = ts.serialize_ros1 if ros == 1 else ts.serialize_cdr
    rows = encode_pose_block(t, pos, q, frame_id, encoding)
    heads = encode_header_block(t, frame_id, encoding)
    for k in range(len(t)):
        want = bytes(ser(pose_stamped(int(t[k]), pos[k], q[k], frame_id, ros), POSE_STAMPED))
        assert rows[k].tobytes() == want
        want_h = bytes(ser(header_msg(int(t[k]), frame_id, ros), HEADER))
        assert heads[k].tobytes() == want_h


def test_block_stamps_outside_the_time_type_are_refused() -> None:
    t = np.array([-1_500_000_000, 0], dtype=np.int64)
    p, q = np.zeros((2, 3)), np.tile([0.0, 0.0, 0.0, 1.0], (2, 1))
    cdr = encode_pose_block(t, p, q, "world", "cdr")  # CDR time is signed: fine
    back = typestore(2).deserialize_cdr(cdr[0].tobytes(), POSE_STAMPED)
    assert (back.header.stamp.sec, back.header.stamp.nanosec) == (-2, 500_000_000)
    with pytest.raises(LogWriteError, match="ROS 1 time cannot be negative"):
        encode_pose_block(t, p, q, "world", "ros1")
    with pytest.raises(LogWriteError, match="do not fit"):
        encode_header_block(np.array([2**31 * 1_000_000_000]), "world", "cdr")


def record(path: Path, fmt: str, per_message: bool, flush_every: int = 37) -> BridgeRecorder:
    """Both sides of 300 ticks, as a bridged run records them (Gazebo poses ahead of the Unity
    frames that apply them, two objects, applied stamps), through one recorder."""
    writer = open_log_writer(path, fmt, metadata={"run": "blocks"})
    rec = BridgeRecorder(
        PerMessage(writer) if per_message else writer,
        unity_map="unity-enu",
        flush_every=flush_every,
        flush_interval_s=1e9,
    )
    assert rec.blocks is not per_message
    t, pos, q = poses(300)
    cam = pos + np.array([-3.0, 0.0, 1.0])
    for k in range(300):
        rec.gazebo_pose("model_rov_pose", int(t[k]), pos[k], q[k])
        rec.gazebo_pose("gui_camera_pose", int(t[k]), cam[k], q[k])
        if k >= 3:  # Unity renders what arrived three ticks ago
            j = k - 3
            rec.unity_pose("model_rov_pose", int(t[k]) + 7, pos[j], q[j], int(t[j]))
            if k % 4:
                rec.unity_pose("gui_camera_pose", int(t[k]) + 7, cam[j], q[j], int(t[j]))
    rec.close()
    return rec


def mcap_messages(path: Path) -> list[tuple[str, int, int, int, bytes, Any]]:
    """(topic, log time, publish time, sequence, raw bytes, decoded message) in file order,
    decoded by mcap_ros2's decoder."""
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    with open(path, "rb") as fh:
        reader = make_reader(fh, decoder_factories=[DecoderFactory()])
        return [
            (ch.topic, m.log_time, m.publish_time, m.sequence, bytes(m.data), dec)
            for _, ch, m, dec in reader.iter_decoded_messages(log_time_order=False)
        ]


def rosbags_messages(path: Path) -> list[tuple[str, int, bytes, Any]]:
    """(topic, log time, raw bytes, decoded message) per message, read by rosbags' AnyReader."""
    from rosbags.highlevel import AnyReader

    with AnyReader([path]) as reader:
        return [
            (c.topic, t, bytes(raw), reader.deserialize(raw, c.msgtype))
            for c, t, raw in reader.messages()
        ]


def fields(msg: Any) -> tuple[Any, ...]:
    """What a decoded PoseStamped / Header says: stamp, frame_id, position, quaternion."""
    head = getattr(msg, "header", msg)
    out: tuple[Any, ...] = (head.stamp.sec, head.stamp.nanosec, head.frame_id)
    if hasattr(msg, "pose"):
        p, o = msg.pose.position, msg.pose.orientation
        out += (p.x, p.y, p.z, o.x, o.y, o.z, o.w)
    return out


@pytest.mark.parametrize("fmt", FORMATS)
def test_block_path_writes_what_the_per_message_path_writes(tmp_path: Path, fmt: str) -> None:
    """Same topics, log times, bytes and decoded fields (exactly), in every simulate format."""
    paths = {}
    for how in ("messages", "blocks"):
        paths[how] = tmp_path / f"{how}{SUFFIX[fmt]}"
        rec = record(paths[how], fmt, per_message=how == "messages")
        assert rec.flushed == rec.written
    assert rec.written["/gazebo/model_rov_pose"] == 300
    assert rec.written["/unity/gui_camera_pose/applied_stamp"] == 223
    if fmt == "mcap":
        a, b = (mcap_messages(paths[h]) for h in ("messages", "blocks"))
        assert [m[:5] for m in a] == [m[:5] for m in b]  # file order, sequence numbers too
        assert [fields(m[5]) for m in a] == [fields(m[5]) for m in b]
    else:
        ra, rb = (rosbags_messages(paths[h]) for h in ("messages", "blocks"))
        assert [m[:3] for m in ra] == [m[:3] for m in rb]
        assert [fields(m[3]) for m in ra if m[0] != "/uwval/metadata"] == [
            fields(m[3]) for m in rb if m[0] != "/uwval/metadata"
        ]
        b = ra  # type: ignore[assignment]
    n = len(b)
    assert n == 300 * 2 + 297 * 2 + 223 * 2 + (1 if fmt == "rosbag1" else 0)
    # uwval's own reader takes the block log as any other
    un = read_stream(paths["blocks"], "/unity/model_rov_pose")
    assert un.frame == "unity-enu" and len(un.t) == 297
    t, pos, _ = poses(300)
    np.testing.assert_array_equal(un.applied_stamp, t[:297])
    np.testing.assert_array_equal(un.position, pos[:297])


def test_mcap_block_file_is_the_mcap_writers_file_byte_for_byte(tmp_path: Path) -> None:
    """Written with the same flushes, McapPoseWriter's file (blocks built with numpy) equals
    the mcap library's (add_message per message): header, metadata, schemas, channels, chunks,
    message indexes, statistics, summary and footer."""
    a, b = tmp_path / "mcap_writer.mcap", tmp_path / "block_writer.mcap"
    writers: dict[Path, Any] = {
        a: McapLibraryWriter(a, metadata={"run": "x"}, chunk_size=1 << 20),
        b: McapPoseWriter(b, metadata={"run": "x"}, chunk_size=1 << 20),
    }
    for path, writer in writers.items():
        rec = BridgeRecorder(writer if path == b else PerMessage(writer), flush_every=500)
        t, pos, q = poses(700)
        for k in range(700):
            rec.gazebo_pose("model_rov_pose", int(t[k]), pos[k], q[k])
            rec.unity_pose("model_rov_pose", int(t[k]) + 3, pos[k], q[k], int(t[k]))
        writer.add_metadata("late", {"n": 700})
        rec.close()
    assert a.read_bytes() == b.read_bytes()
    report = scan_mcap(b)
    assert report.complete and report.lost_bytes == 0, report.describe()
    assert report.messages["/unity/model_rov_pose/applied_stamp"] == 700


def test_ros1_block_file_is_the_rosbags_writers_file_byte_for_byte(tmp_path: Path) -> None:
    """The recorder's blocks into a ROS 1 bag give the bag of one write per message (rosbags'
    Writer): bag header, connection records, chunks split after the message that passes
    1 MiB (here several, some inside one recorder block), index data, chunk infos."""
    a, b = tmp_path / "rosbags.bag", tmp_path / "blocks.bag"
    n = 9000
    t, pos, q = poses(n)
    for path in (a, b):
        writer = Rosbag1PoseWriter(path, metadata={"run": "x"})
        rec = BridgeRecorder(writer if path == b else PerMessage(writer), flush_every=20000)
        for k in range(n):
            rec.gazebo_pose("model_rov_pose", int(t[k]), pos[k], q[k])
            if k % 3:
                rec.unity_pose("gui_camera_pose", int(t[k]) + 3, pos[k], q[k], int(t[k]))
        rec.close()
    assert a.read_bytes() == b.read_bytes()
    assert len(rosbags_messages(b)) == 1 + n + 2 * (n - n // 3)


def test_block_writer_refuses_what_mcap_cannot_hold(tmp_path: Path) -> None:
    w = McapPoseWriter(tmp_path / "neg.mcap")
    with pytest.raises(LogWriteError, match="negative log time"):
        w.write_pose("/p", 5, np.zeros(3), np.array([0.0, 0.0, 0.0, 1.0]), "world", -1)
    w.close()
    w.close()  # idempotent
    with pytest.raises(LogWriteError, match="closed"):
        w.write_header("/h", 1, 1)
    rec = BridgeRecorder(McapPoseWriter(tmp_path / "bad.mcap"))
    rec.gazebo_pose("model_rov_pose", 1, np.zeros(2), np.array([0.0, 0.0, 0.0, 1.0]))
    with pytest.raises(LogWriteError, match="/gazebo/model_rov_pose: a pose is not 3"):
        rec.flush()
    with pytest.raises(LogWriteError, match="cannot open"):
        McapPoseWriter(tmp_path / "no" / "such" / "dir.mcap")
    with pytest.raises(LogWriteError, match="cannot create ROS 1 bag"):
        Rosbag1PoseWriter(tmp_path)  # a directory
    old = tmp_path / "old.bag"
    old.write_bytes(b"an earlier log")
    with open_log_writer(old, "rosbag1") as w:  # replaced, as uwval's writers do
        w.write_header("/h", 5, 5, "world")
        with pytest.raises(LogWriteError, match="outside ROS 1 time"):
            w.write_header("/h", 5, -5, "world")
    assert [m[:2] for m in rosbags_messages(old)] == [("/h", 5)]
