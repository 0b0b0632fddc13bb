"""Vectorised encode of PoseStamped and Header messages (ROS 2 CDR and ROS 1).

All messages of one call share the frame_id, hence one byte layout: the payloads are built
as one (N, L) uint8 array whose columns are filled through numpy views. The tests check the
bytes are identical to rosbags' per-message serialization.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from uwval.errors import LogWriteError

U8 = NDArray[np.uint8]
I64 = NDArray[np.int64]


def _split(t_ns: ArrayLike, encoding: str, what: str) -> tuple[I64, I64]:
    """(sec, nsec) of each stamp (ns) as ``divmod(t, 1e9)``, checked to fit the message's
    time type (CDR: int32 seconds; ROS 1: uint32 seconds, not negative)."""
    t = np.asarray(t_ns, dtype=np.int64).reshape(-1)
    sec, nsec = np.divmod(t, 1_000_000_000)
    if sec.size:
        lo, hi = int(sec.min()), int(sec.max())
        if encoding == "ros1" and lo < 0:
            raise LogWriteError(
                f"{what}: ROS 1 time cannot be negative (stamp {int(t[sec < 0][0])} ns)"
            )
        if hi > (2**32 - 1 if encoding == "ros1" else 2**31 - 1) or lo < -(2**31):
            bad = lo if lo < -(2**31) else hi
            raise LogWriteError(f"{what}: stamp seconds {bad} do not fit the message's time type")
    return sec, nsec


def _put(rows: U8, at: int, values: NDArray[np.generic], dtype: str) -> None:
    """Write ``values`` (N, k) or (N,) as little-endian ``dtype`` at byte column ``at``."""
    v = np.ascontiguousarray(values, dtype=dtype).reshape(rows.shape[0], -1)
    width = v.shape[1] * v.dtype.itemsize
    rows[:, at : at + width] = v.view(np.uint8).reshape(rows.shape[0], width)


def _header(encoding: str, n: int, frame_id: str, tail: int) -> tuple[U8, int, int]:
    """Rows with the header written except the stamp; returns (rows, stamp_at, body_at).

    ``tail`` is the body size in bytes (float64s, 8-aligned in CDR).
    """
    fid = frame_id.encode()
    if encoding == "cdr":
        slen = len(fid) + 1  # CDR strings count and store the NUL
        body = 8 + 4 + slen  # relative to the alignment origin (after the 4-byte header)
        body_al = (body + 7) // 8 * 8 if tail else body
        size = 4 + body_al + tail
        rows = np.zeros((n, size), dtype=np.uint8)
        rows[:, 1] = 1  # encapsulation: CDR little-endian
        rows[:, 12:16] = np.frombuffer(np.uint32(slen).tobytes(), np.uint8)
        rows[:, 16 : 16 + len(fid)] = np.frombuffer(fid, np.uint8)
        return rows, 4, 4 + body_al
    slen = len(fid)
    size = 4 + 8 + 4 + slen + tail
    rows = np.zeros((n, size), dtype=np.uint8)  # seq = 0, as rosbag record writes it
    rows[:, 12:16] = np.frombuffer(np.uint32(slen).tobytes(), np.uint8)
    rows[:, 16 : 16 + slen] = np.frombuffer(fid, np.uint8)
    return rows, 4, 16 + slen


def encode_pose_stamped(
    t_ns: ArrayLike, position: ArrayLike, quat: ArrayLike, frame_id: str, encoding: str = "cdr"
) -> U8:
    """(N, L) payload rows of geometry_msgs/PoseStamped, one message per row.

    ``position`` (N, 3) metres and ``quat`` (N, 4) x y z w are written as they are (the
    caller chooses the frame); ``t_ns`` int64 ns becomes header.stamp (sec, nanosec).
    """
    pos = np.asarray(position, dtype=np.float64).reshape(-1, 3)
    q = np.asarray(quat, dtype=np.float64).reshape(-1, 4)
    n = pos.shape[0]
    rows, stamp_at, body_at = _header(encoding, n, frame_id, 56)
    sec, nsec = _split(t_ns, encoding, f"PoseStamped {frame_id!r}")
    _put(rows, stamp_at, sec, "<i4" if encoding == "cdr" else "<u4")
    _put(rows, stamp_at + 4, nsec, "<u4")
    _put(rows, body_at, np.concatenate([pos, q], axis=1), "<f8")
    return rows


def encode_header(stamp_ns: ArrayLike, frame_id: str = "", encoding: str = "cdr") -> U8:
    """(N, L) payload rows of std_msgs/Header stamped ``stamp_ns``."""
    sec, nsec = _split(stamp_ns, encoding, f"Header {frame_id!r}")
    rows, stamp_at, _ = _header(encoding, sec.shape[0], frame_id, 0)
    _put(rows, stamp_at, sec, "<i4" if encoding == "cdr" else "<u4")
    _put(rows, stamp_at + 4, nsec, "<u4")
    return rows
