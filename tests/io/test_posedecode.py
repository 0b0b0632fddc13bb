"""The C pass over uniform pose rows (uwval/io/_posedecode.c) against the numpy decode it
replaces: on every input, with mutations anywhere in any row, fast_decode gives the same
stamps, poses (to the bit), names, codes and handled rows with the pass and without it."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from accelerators import require_module
from uwval.io import fastdecode
from uwval.io.encode import encode_header, encode_pose_stamped
from uwval.io.ros import typestore

require_module(fastdecode._posedecode, "uwval.io._posedecode")

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


def _decode(rows: np.ndarray, msgtype: str, encoding: str, accel: bool, mp: Any) -> Any:
    mp.setattr(fastdecode, "USE_ACCELERATOR", accel)
    n, w = rows.shape
    buf = np.ascontiguousarray(rows).reshape(-1)
    off = np.arange(n, dtype=np.int64) * w
    return fastdecode.fast_decode(msgtype, encoding, buf, off, np.full(n, w, dtype=np.int64))


def _same(a: Any, b: Any) -> None:
    np.testing.assert_array_equal(a.stamp, b.stamp)
    # bit patterns: NaN payloads and -0.0 included
    np.testing.assert_array_equal(a.position.view(np.int64), b.position.view(np.int64))
    np.testing.assert_array_equal(a.orientation.view(np.int64), b.orientation.view(np.int64))
    np.testing.assert_array_equal(a.frame_code, b.frame_code)
    np.testing.assert_array_equal(a.child_code, b.child_code)
    np.testing.assert_array_equal(a.handled, b.handled)
    assert a.names == b.names
    for arr in (a.position, a.orientation):
        assert arr.flags.c_contiguous


@pytest.mark.parametrize("encoding", ["cdr", "ros1"])
@pytest.mark.parametrize("msgtype", [PS, HDR, TS])
@pytest.mark.parametrize("frame", ["world", "", "odom_frame_with_a_long_name", "wörld"])
def test_uniform_rows_take_the_c_pass_and_decode_as_numpy_does(
    msgtype: str, encoding: str, frame: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    rows = _rows(msgtype, 300, frame, encoding, seed=len(frame))
    calls: list[int] = []
    real = fastdecode._posedecode.decode_uniform

    def counting(*args: Any) -> int:
        got = real(*args)
        calls.append(got)
        return got

    monkeypatch.setattr(fastdecode._posedecode, "decode_uniform", counting)
    fast = _decode(rows, msgtype, encoding, True, monkeypatch)
    assert calls == [-1], "uniform rows must be decoded by the C pass"
    slow = _decode(rows, msgtype, encoding, False, monkeypatch)
    _same(fast, slow)
    assert fast.handled.all()
    assert fast.names[0] == frame


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
def test_rows_changed_anywhere_decode_the_same_with_the_c_pass_and_without(
    msgtype: str,
    encoding: str,
    frame: str,
    n: int,
    edits: list[tuple[int, int, int]],
    seed: int,
) -> None:
    """Byte edits anywhere (encapsulation, string lengths, names, NULs, stamps, doubles):
    the C pass either declines (numpy decides row by row) or answers as numpy does."""
    rows = _rows(msgtype, n, frame, encoding, seed).copy()
    for r, c, v in edits:
        rows[r % n, c % rows.shape[1]] = v
    with pytest.MonkeyPatch.context() as mp:
        fast = _decode(rows, msgtype, encoding, True, mp)
        slow = _decode(rows, msgtype, encoding, False, mp)
    _same(fast, slow)


def test_a_row_with_another_name_of_the_same_length_is_left_to_numpy(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    rows = _rows(PS, 50, "left", "cdr", seed=1).copy()
    rows[17, 16:20] = np.frombuffer(b"rght", dtype=np.uint8)
    monkeypatch.setattr(fastdecode, "USE_ACCELERATOR", True)
    n, w = rows.shape
    acc = fastdecode._Bytes(rows.reshape(-1), np.arange(n) * w, np.full(n, w))
    assert fastdecode._decode_uniform(fastdecode.LAYOUTS[PS], acc, True) is None
    fast = _decode(rows, PS, "cdr", True, monkeypatch)
    assert fast.names == ["left", "rght"] and fast.frame_code[17] == 1
    _same(fast, _decode(rows, PS, "cdr", False, monkeypatch))


def test_bad_arguments_are_refused_without_reading_outside_the_rows() -> None:
    dec = fastdecode._posedecode.decode_uniform
    rows = np.zeros((4, 80), dtype=np.uint8)
    stamp, pos, quat = np.empty(4, np.int64), np.empty((4, 3)), np.empty((4, 4))
    ok = np.array([[0, 2]], dtype=np.int64)
    assert dec(rows, 80, ok, 4, 24, stamp, pos, quat) == -1
    for args in (
        (rows, 0, ok, 4, 24),  # no width
        (rows, 70, ok, 4, 24),  # not whole rows
        (rows, 80, np.array([[79, 2]], dtype=np.int64), 4, 24),  # range past the row
        (rows, 80, np.array([[-1, 2]], dtype=np.int64), 4, 24),
        (rows, 80, ok, 73, 24),  # stamp past the row
        (rows, 80, ok, 4, 25),  # pose past the row
    ):
        with pytest.raises(ValueError, match="decode_uniform"):
            dec(*args, stamp, pos, quat)
    with pytest.raises(ValueError, match="decode_uniform"):
        dec(rows, 80, ok, 4, 24, np.empty(3, np.int64), pos, quat)  # outputs too small
    with pytest.raises(ValueError, match="contiguous"):
        dec(rows, 80, ok, 4, 24, stamp, pos, np.empty((4, 4)).T)
