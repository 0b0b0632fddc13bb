"""Decode a topic's raw payloads into pose columns: fast path first, rosbags for the rest.

:func:`decode_poses` handles PoseStamped, Pose, PoseWithCovariance(Stamped), TransformStamped,
Transform, Odometry and Header; :func:`decode_tf` handles tf2_msgs/TFMessage (and ROS 1's
``tf/tfMessage``), returning one row per transform. Per-message decode uses rosbags'
typestores (ROS 2 Humble for CDR, ROS 1 Noetic for ROS 1), with the log's own message
definition registered when the type is not in the store.
"""

from __future__ import annotations

from functools import lru_cache
from typing import Any

import numpy as np

from uwval.errors import LogReadError
from uwval.io.fastdecode import LAYOUTS, Decoded, fast_decode
from uwval.io.raw import RawTopic
from uwval.io.ros import typestore

TF_TYPES = ("tf2_msgs/msg/TFMessage", "tf/msg/tfMessage")
POSE_TYPES = tuple(t for t in LAYOUTS if t != "std_msgs/msg/Header")


@lru_cache(maxsize=32)
def _store_for(encoding: str, msgtype: str, msgdef: str) -> Any:
    """A typestore that knows ``msgtype`` (the stock one, or one extended from ``msgdef``)."""
    base = typestore(1 if encoding == "ros1" else 2)
    if msgtype in base.types or not msgdef:
        return base
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.ROS1_NOETIC if encoding == "ros1" else Stores.ROS2_HUMBLE)
    store.register(get_types_from_msg(msgdef, msgtype))
    return store


def deserialize(raw: RawTopic, i: int) -> Any:
    """Message ``i`` of ``raw`` as a rosbags message object (the reference decode)."""
    store = _store_for(raw.encoding, raw.msgtype, raw.msgdef)
    data = raw.payload(i)
    if raw.encoding == "ros1":
        return store.deserialize_ros1(data, raw.msgtype)
    if raw.encoding == "cdr":
        return store.deserialize_cdr(data, raw.msgtype)
    raise LogReadError(f"topic {raw.name}: message encoding {raw.encoding!r} is not supported")


def _stamp(h: Any) -> int:
    return int(h.stamp.sec) * 1_000_000_000 + int(h.stamp.nanosec)


def _pose7(p: Any) -> tuple[float, ...]:
    a, b = (p.position, p.orientation) if hasattr(p, "position") else (p.translation, p.rotation)
    return (a.x, a.y, a.z, b.x, b.y, b.z, b.w)


def _fields(msgtype: str, msg: Any) -> tuple[int, tuple[float, ...] | None, str | None, str | None]:
    """(stamp ns or -1, pose, frame_id, child_frame_id) of one decoded message."""
    if msgtype not in LAYOUTS:
        raise LogReadError(f"message type {msgtype} carries no pose")
    header = msg if msgtype.endswith("/Header") else getattr(msg, "header", None)
    body = getattr(msg, "transform", None) or getattr(msg, "pose", msg)
    while hasattr(body, "pose"):  # PoseWithCovariance(Stamped), Odometry: pose.pose
        body = body.pose
    pose = None if header is msg else _pose7(body)
    if header is None:
        return -1, pose, None, None
    return _stamp(header), pose, header.frame_id, getattr(msg, "child_frame_id", None)


def decode_poses(raw: RawTopic, *, fast: bool = True, errors: str = "raise") -> Decoded:
    """Pose columns of every message of ``raw`` (row i = message i).

    ``fast=False`` forces the per-message rosbags decode (the reference the tests compare to).
    ``errors="drop"`` leaves a message that cannot be decoded unhandled (``handled[i]`` False)
    instead of raising; the caller counts it. Raises :class:`LogReadError` when every message
    fails (naming the first failure).
    """
    if raw.msgtype not in LAYOUTS:
        raise LogReadError(
            f"topic {raw.name}: type {raw.msgtype or '(unknown)'} is not a pose type; "
            "supported: " + ", ".join(sorted(LAYOUTS)) + ", " + ", ".join(TF_TYPES)
        )
    n = len(raw)
    fast_args = (raw.msgtype, raw.encoding, raw.buf, raw.offset, raw.length)
    dec = fast_decode(*fast_args) if fast else Decoded.empty(n)
    rest = np.flatnonzero(~dec.handled)
    if rest.size and raw.encoding not in ("cdr", "ros1"):
        raise LogReadError(f"topic {raw.name}: message encoding {raw.encoding!r} is not supported")
    first: LogReadError | None = None
    for i in rest:
        try:
            msg = deserialize(raw, int(i))
            stamp, pose, frame_id, child = _fields(raw.msgtype, msg)
        except Exception as exc:
            err = LogReadError(
                f"topic {raw.name}: message {int(i)} (log time {int(raw.log_time[i])} ns) "
                f"cannot be decoded as {raw.msgtype}: {' '.join(str(exc).split())}"
            )
            if errors != "drop":
                raise err from exc
            first = first or err
            continue
        dec.stamp[i] = stamp
        if pose is not None:
            dec.set_pose(i, pose)
        if frame_id is not None:
            dec.frame_code[i] = dec.code(frame_id)
        if child is not None:
            dec.child_code[i] = dec.code(child)
        dec.handled[i] = True
    if first is not None and n and not dec.handled.any():
        raise first
    return dec


def decode_tf(raw: RawTopic, *, errors: str = "raise") -> tuple[Decoded, int]:
    """One row per transform in a TFMessage topic (stamp, pose, parent in frame, child), and
    the number of messages that could not be decoded (``errors="drop"``; else they raise)."""
    rows: list[tuple[int, tuple[float, ...], str, str]] = []
    bad = 0
    first: LogReadError | None = None
    for i in range(len(raw)):
        try:
            rows += [
                (_stamp(tr.header), _pose7(tr.transform), tr.header.frame_id, tr.child_frame_id)
                for tr in deserialize(raw, i).transforms
            ]
        except Exception as exc:
            err = LogReadError(
                f"topic {raw.name}: message {i} cannot be decoded as {raw.msgtype}: "
                + " ".join(str(exc).split())
            )
            if errors != "drop":
                raise err from exc
            first, bad = first or err, bad + 1
    if first is not None and bad == len(raw):
        raise first
    dec = Decoded.empty(len(rows))
    if rows:
        stamps, poses, parents, children = zip(*rows, strict=True)
        dec.stamp[:] = stamps
        dec.set_pose(slice(None), poses)
        dec.frame_code[:] = [dec.code(p.strip("/")) for p in parents]
        dec.child_code[:] = [dec.code(c.strip("/")) for c in children]
        dec.handled[:] = True
    return dec, bad
