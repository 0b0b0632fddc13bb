"""ROS-TCP framing and message bodies (uwval.bridge.protocol) vs the protocol facts and rosbags."""

from __future__ import annotations

import itertools
import json
import struct

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from uwval.bridge import protocol as wire
from uwval.io.ros import pose_stamped, typestore

PS = "geometry_msgs/msg/PoseStamped"

finite = st.floats(allow_nan=False, allow_infinity=False, width=64)
frame_ids = st.text(alphabet=st.characters(min_codepoint=32, max_codepoint=0x2FF), max_size=20)
stamps = st.integers(min_value=0, max_value=2**31 * 10**9 - 1)


@settings(max_examples=150, deadline=None)
@given(
    t=stamps,
    p=st.lists(finite, min_size=3, max_size=3),
    q=st.lists(finite, min_size=4, max_size=4),
    fid=frame_ids,
)
def test_pose_fast_path_is_byte_identical_to_rosbags(
    t: int, p: list[float], q: list[float], fid: str
) -> None:
    pos, quat = np.array(p), np.array(q)
    ros2 = bytes(typestore(2).serialize_cdr(pose_stamped(t, pos, quat, fid), PS))
    ros1 = bytes(typestore(1).serialize_ros1(pose_stamped(t, pos, quat, fid, ros_version=1), PS))
    assert wire.encode_pose_stamped(t, pos, quat, fid, "ROS2") == ros2
    assert wire.encode_pose_stamped(t, pos, quat, fid, "ROS1") == ros1
    assert ros2[:4] == b"\x00\x01\x00\x00"  # CDR little-endian encapsulation header
    for body, proto in ((ros2, "ROS2"), (ros1, "ROS1")):
        t2, p2, q2, f2 = wire.decode_pose_stamped(body, proto)  # type: ignore[arg-type]
        assert (t2, f2) == (t, fid)
        np.testing.assert_array_equal(p2, pos)
        np.testing.assert_array_equal(q2, quat)


def test_decode_agrees_with_rosbags_deserializer() -> None:
    body = wire.encode_pose_stamped(
        12_000_000_007, [1.5, -2.0, 3.25], [0.0, 0.6, 0.0, 0.8], "world"
    )
    msg = wire.decode_with_rosbags(body, "geometry_msgs/PoseStamped")
    assert (msg.header.stamp.sec, msg.header.stamp.nanosec) == (12, 7)
    assert msg.header.frame_id == "world"
    assert (msg.pose.position.x, msg.pose.orientation.y) == (1.5, 0.6)


def test_malformed_pose_body_is_a_clear_error() -> None:
    body = wire.encode_pose_stamped(0, [0, 0, 0], [0, 0, 0, 1], "world")
    with pytest.raises(wire.ProtocolError, match="PoseStamped body of 30 bytes"):
        wire.decode_pose_stamped(body[:30])
    with pytest.raises(wire.ProtocolError, match="encapsulation header"):
        wire.decode_pose_stamped(b"\x01\x00\x00\x00" + body[4:])
    with pytest.raises(wire.ProtocolError, match="ROS 1 time cannot be negative"):
        wire.encode_pose_stamped(-1, [0, 0, 0], [0, 0, 0, 1], "", "ROS1")


# --------------------------------------------------------------------------- framing


def _frame_by_hand(dest: bytes, payload: bytes) -> bytes:
    return struct.pack("<I", len(dest)) + dest + struct.pack("<I", len(payload)) + payload


def test_frame_layout_matches_the_wire_facts() -> None:
    assert wire.encode_frame("topic", b"abc") == _frame_by_hand(b"topic", b"abc")
    assert wire.encode_frame("topic", b"abc", nul=True) == _frame_by_hand(b"topic\x00", b"abc")
    assert wire.KEEPALIVE == _frame_by_hand(b"", b"") == b"\x00" * 8
    sub = wire.encode_command("__subscribe", {"topic": "a", "message_name": "x/Y"}, nul=True)
    dlen = struct.unpack_from("<I", sub)[0]
    assert sub[4 : 4 + dlen] == b"__subscribe\x00"
    payload = sub[8 + dlen :]
    assert payload.endswith(b"\x00")
    assert json.loads(payload[:-1]) == {"topic": "a", "message_name": "x/Y"}


def test_handshake_payload_is_exact() -> None:
    frame = wire.FrameParser().feed(wire.handshake_frame("ROS2"))[0]
    assert frame.destination == "__handshake"
    assert json.loads(frame.payload) == {"version": "v0.7.0", "metadata": '{"protocol": "ROS2"}'}
    assert wire.parse_handshake(frame) == ("v0.7.0", "ROS2")
    ros1 = wire.FrameParser().feed(wire.handshake_frame("ROS1"))[0]
    assert wire.parse_handshake(ros1) == ("v0.7.0", "ROS1")


def test_handshake_rejects_other_versions() -> None:
    bad = wire.encode_command("__handshake", {"version": "v0.6.0", "metadata": "{}"})
    with pytest.raises(wire.ProtocolError, match=r"unsupported ROS-TCP version 'v0\.6\.0'"):
        wire.parse_handshake(wire.FrameParser().feed(bad)[0])
    newer_patch = wire.encode_command(
        "__handshake", {"version": "v0.7.3", "metadata": json.dumps({"protocol": "ROS1"})}
    )
    assert wire.parse_handshake(wire.FrameParser().feed(newer_patch)[0]) == ("v0.7.3", "ROS1")


frames_st = st.lists(
    st.tuples(
        st.text(max_size=30).filter(lambda s: "\x00" not in s),
        st.binary(max_size=300),
        st.booleans(),
    ),
    max_size=12,
)


@settings(max_examples=150, deadline=None)
@given(frames=frames_st, cuts=st.lists(st.integers(min_value=0, max_value=5000), max_size=20))
def test_parser_reassembles_frames_split_anywhere(
    frames: list[tuple[str, bytes, bool]], cuts: list[int]
) -> None:
    stream = b"".join(wire.encode_frame(d, p, nul=n) for d, p, n in frames)
    points = sorted({c % (len(stream) + 1) for c in cuts} | {0, len(stream)})
    parser = wire.FrameParser()
    got = []
    for a, b in itertools.pairwise(points):
        got.extend(parser.feed(stream[a:b]))
    assert [(f.destination, f.payload) for f in got] == [(d, p) for d, p, _ in frames]
    assert parser.buffered == 0
    offsets = [f.offset for f in got]
    assert offsets == sorted(offsets)


def test_oversized_frame_names_byte_offset() -> None:
    parser = wire.FrameParser(max_frame=100)
    ok = wire.encode_frame("a", b"x" * 100)
    assert len(parser.feed(ok)) == 1
    bad = struct.pack("<I", 1) + b"b" + struct.pack("<I", 101)
    with pytest.raises(wire.ProtocolError, match=f"at byte {len(ok)}: payload length 101"):
        parser.feed(bad)
    with pytest.raises(wire.ProtocolError):  # the parser stays failed: framing is lost
        parser.feed(wire.KEEPALIVE)


def test_long_destination_and_bad_utf8_are_rejected() -> None:
    with pytest.raises(wire.ProtocolError, match="destination length 5000"):
        wire.FrameParser().feed(struct.pack("<I", 5000) + b"zz")
    with pytest.raises(wire.ProtocolError, match="not valid UTF-8"):
        wire.FrameParser().feed(_frame_by_hand(b"\xff\xfe", b""))
    with pytest.raises(wire.ProtocolError, match="embedded NUL"):
        wire.FrameParser().feed(_frame_by_hand(b"a\x00b", b""))


def test_json_payloads_with_and_without_nul() -> None:
    assert wire.decode_json(b'{"a": 1}\x00') == {"a": 1}
    assert wire.decode_json(b'{"a": 1}') == {"a": 1}
    assert wire.decode_json(b"") == {}
    with pytest.raises(wire.ProtocolError, match="invalid JSON"):
        wire.decode_json(b"{nope", where="__subscribe at byte 7")
    with pytest.raises(wire.ProtocolError, match="must be an object"):
        wire.decode_json(b"[1]")


def test_message_names_travel_as_pkg_type() -> None:
    assert wire.message_name("geometry_msgs/msg/PoseStamped") == "geometry_msgs/PoseStamped"
    assert wire.message_name("std_msgs/Header") == "std_msgs/Header"
    with pytest.raises(wire.ProtocolError, match="expected pkg/Type"):
        wire.message_name("PoseStamped")
    assert wire.known_message_type("geometry_msgs/PoseStamped")
    assert not wire.known_message_type("nope_msgs/Nothing")
