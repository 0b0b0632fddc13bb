"""The vectorised fixed-layout decoder (uwval.io.fastdecode) against rosbags' per-message
deserialisation, the reference: on uniform rows and with byte edits anywhere in any row, every
row the fast path claims holds rosbags' stamp, pose (to the bit) and frame names; the rows it
declines are left to rosbags by decode_poses."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from uwval.io import fastdecode
from uwval.io.decode import decode_poses, deserialize
from uwval.io.encode import encode_header, encode_pose_stamped
from uwval.io.raw import RawTopic
from uwval.io.ros import typestore

PS, HDR, TS = (
    "geometry_msgs/msg/PoseStamped",
    "std_msgs/msg/Header",
    "geometry_msgs/msg/TransformStamped",
)


def _transform_rows(n: int, frame: str, child: str, encoding: str, seed: int) -> np.ndarray:
    """n TransformStamped payloads serialized by rosbags (the reference serializer)."""
    ts = typestore(2 if encoding == "cdr" else 1)
    T = ts.types
    rng = np.random.default_rng(seed)
    rows = []
    for k in range(n):
        v, q = rng.normal(size=3), rng.normal(size=4)
        msg = T[TS](
            header=T["std_msgs/msg/Header"](
                stamp=T["builtin_interfaces/msg/Time"](sec=int(k), nanosec=int(k * 1000)),
                frame_id=frame,
                **({"seq": 0} if encoding == "ros1" else {}),
            ),
            child_frame_id=child,
            transform=T["geometry_msgs/msg/Transform"](
                translation=T["geometry_msgs/msg/Vector3"](x=v[0], y=v[1], z=v[2]),
                rotation=T["geometry_msgs/msg/Quaternion"](x=q[0], y=q[1], z=q[2], w=q[3]),
            ),
        )
        data = ts.serialize_cdr(msg, TS) if encoding == "cdr" else ts.serialize_ros1(msg, TS)
        rows.append(np.frombuffer(bytes(data), dtype=np.uint8))
    return np.stack(rows)


def _rows(msgtype: str, n: int, frame: str, encoding: str, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    t = rng.integers(0, 2**31 - 1, size=n) * 1_000_000_000 + rng.integers(0, 10**9, size=n)
    if msgtype == PS:
        q = rng.normal(size=(n, 4))
        return encode_pose_stamped(t, rng.normal(size=(n, 3)), q, frame, encoding)
    if msgtype == HDR:
        return encode_header(t, frame, encoding)
    return _transform_rows(n, frame, frame[::-1] + "_child", encoding, seed)


def _raw(rows: np.ndarray, msgtype: str, encoding: str) -> RawTopic:
    n, w = rows.shape
    return RawTopic(
        name="/t",
        msgtype=msgtype,
        encoding=encoding,
        log_time=np.arange(n, dtype=np.int64),
        buf=np.ascontiguousarray(rows).reshape(-1),
        offset=np.arange(n, dtype=np.int64) * w,
        length=np.full(n, w, dtype=np.int64),
    )


def _reference(raw: RawTopic, i: int) -> tuple[int, list[float], list[str]] | None:
    """rosbags' stamp (ns), 7 pose values and frame names of message i, or None if it fails."""
    try:
        msg = deserialize(raw, i)
    except Exception:
        return None
    header = msg if raw.msgtype == HDR else msg.header
    stamp = int(header.stamp.sec) * 1_000_000_000 + int(header.stamp.nanosec)
    names = [header.frame_id] + ([msg.child_frame_id] if raw.msgtype == TS else [])
    if raw.msgtype == HDR:
        return stamp, [], names
    p, q = (
        (msg.pose.position, msg.pose.orientation)
        if raw.msgtype == PS
        else (
            msg.transform.translation,
            msg.transform.rotation,
        )
    )
    return stamp, [p.x, p.y, p.z, q.x, q.y, q.z, q.w], names


def _agrees_with_rosbags(dec: Any, raw: RawTopic) -> None:
    """Every row the fast path handled is rosbags' message, bit for bit."""
    for i in np.flatnonzero(dec.handled).tolist():
        ref = _reference(raw, i)
        assert ref is not None, f"row {i}: fast path decoded a message rosbags refuses"
        stamp, pose, names = ref
        assert int(dec.stamp[i]) == stamp
        if pose:
            got = np.concatenate([dec.position[i], dec.orientation[i]])
            assert got.view(np.int64).tolist() == np.array(pose).view(np.int64).tolist()
        assert dec.names[int(dec.frame_code[i])] == names[0]
        if len(names) > 1:
            assert dec.names[int(dec.child_code[i])] == names[1]


@pytest.mark.parametrize("encoding", ["cdr", "ros1"])
@pytest.mark.parametrize("msgtype", [PS, HDR, TS])
@pytest.mark.parametrize("frame", ["world", "", "odom_frame_with_a_long_name", "wörld"])
def test_uniform_rows_are_all_decoded_as_rosbags_does(
    msgtype: str, encoding: str, frame: str
) -> None:
    raw = _raw(_rows(msgtype, 300, frame, encoding, seed=len(frame)), msgtype, encoding)
    dec = fastdecode.fast_decode(msgtype, encoding, raw.buf, raw.offset, raw.length)
    assert dec.handled.all()
    assert dec.names[0] == frame
    for arr in (dec.position, dec.orientation):
        assert arr.flags.c_contiguous
    _agrees_with_rosbags(dec, raw)
    slow = decode_poses(raw, fast=False)  # the whole topic through rosbags
    np.testing.assert_array_equal(dec.stamp, slow.stamp)
    assert dec.position.tobytes() == slow.position.tobytes()
    assert dec.orientation.tobytes() == slow.orientation.tobytes()


@settings(max_examples=150, deadline=None)
@given(
    msgtype=st.sampled_from([PS, HDR, TS]),
    encoding=st.sampled_from(["cdr", "ros1"]),
    frame=st.sampled_from(["world", "map", "", "base_link_2"]),
    n=st.integers(2, 40),
    edits=st.lists(
        st.tuples(st.integers(0, 10**6), st.integers(0, 10**6), st.integers(0, 255)),
        max_size=6,
    ),
    seed=st.integers(0, 2**16),
)
def test_rows_changed_anywhere_are_decoded_as_rosbags_does_or_left_to_it(
    msgtype: str,
    encoding: str,
    frame: str,
    n: int,
    edits: list[tuple[int, int, int]],
    seed: int,
) -> None:
    """Byte edits anywhere (encapsulation, string lengths, names, NULs, stamps, doubles):
    a row the fast path claims is rosbags' message; decode_poses then agrees with rosbags on
    every row rosbags can read."""
    rows = _rows(msgtype, n, frame, encoding, seed).copy()
    for r, c, v in edits:
        rows[r % n, c % rows.shape[1]] = v
    raw = _raw(rows, msgtype, encoding)
    dec = fastdecode.fast_decode(msgtype, encoding, raw.buf, raw.offset, raw.length)
    _agrees_with_rosbags(dec, raw)
    both = decode_poses(raw, errors="drop") if dec.handled.any() else None
    if both is not None:
        readable = [i for i in range(n) if _reference(raw, i) is not None]
        assert np.flatnonzero(both.handled).tolist() == readable


def test_a_row_with_another_name_of_the_same_length_gets_its_own_code() -> None:
    rows = _rows(PS, 50, "left", "cdr", seed=1).copy()
    rows[17, 16:20] = np.frombuffer(b"rght", dtype=np.uint8)
    raw = _raw(rows, PS, "cdr")
    dec = fastdecode.fast_decode(PS, "cdr", raw.buf, raw.offset, raw.length)
    assert dec.handled.all()
    assert dec.names == ["left", "rght"] and dec.frame_code[17] == 1
    _agrees_with_rosbags(dec, raw)
