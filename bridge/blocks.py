"""Blocks of serialized pose messages: PoseStamped / Header bodies of a whole block encoded
with numpy at once (fixed-width rows, rosbags' bytes), and the record of one topic's block that
the recorder hands to a log writer (:class:`RawBlock`, :func:`write_raw_blocks`)."""

from __future__ import annotations

import struct
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from uwval.errors import LogWriteError
from uwval.io.ros import HEADER, POSE_STAMPED

F64 = NDArray[np.float64]
U8 = NDArray[np.uint8]
I64 = NDArray[np.int64]

_NS = 1_000_000_000
_CDR_HEADER = b"\x00\x01\x00\x00"
_INT32_MAX = 2**31 - 1
_UINT32_MAX = 2**32 - 1


def _stamp_fields(stamps_ns: I64, encoding: str, what: str) -> tuple[I64, I64]:
    """(sec, nsec) of each stamp (ns), as ``divmod(t, 1e9)`` does; checked to fit the
    message's time type (CDR: int32 seconds; ROS 1: uint32 seconds)."""
    sec, nsec = np.divmod(stamps_ns, _NS)
    if sec.size:
        lo, hi = int(sec.min()), int(sec.max())
        if encoding == "ros1" and lo < 0:
            raise LogWriteError(
                f"{what}: ROS 1 time cannot be negative (stamp {int(stamps_ns[sec < 0][0])} ns)"
            )
        top = _UINT32_MAX if encoding == "ros1" else _INT32_MAX
        if hi > top or lo < -_INT32_MAX - 1:
            bad = hi if hi > top else lo
            raise LogWriteError(f"{what}: stamp seconds {bad} do not fit the message's time type")
    return sec, nsec


def _head_template(frame_id: str, encoding: str, pad_to: int) -> tuple[bytes, int]:
    """Bytes of a message up to the end of its Header (stamp fields zero), and the offset of
    the stamp's seconds field. ``pad_to``: align the end to this (CDR doubles: 8)."""
    fid = frame_id.encode("utf-8")
    if encoding == "ros1":  # seq (0), secs, nsecs, len(frame_id), frame_id
        return struct.pack("<IIII", 0, 0, 0, len(fid)) + fid, 4
    head = struct.pack("<iII", 0, 0, len(fid) + 1) + fid + b"\x00"
    pad = -len(head) % pad_to if pad_to > 1 else 0
    return _CDR_HEADER + head + b"\x00" * pad, 4


def _fill_stamps(rows: U8, sec: I64, nsec: I64, at: int, encoding: str) -> None:
    n = rows.shape[0]
    sec_dt = "<u4" if encoding == "ros1" else "<i4"
    rows[:, at : at + 4] = sec.astype(sec_dt).view(np.uint8).reshape(n, 4)
    rows[:, at + 4 : at + 8] = nsec.astype("<u4").view(np.uint8).reshape(n, 4)


def encode_pose_block(
    stamps_ns: I64, position: F64, orientation: F64, frame_id: str, encoding: str = "cdr"
) -> U8:
    """A block of geometry_msgs/PoseStamped bodies, one row each: (n, width) uint8.

    ``stamps_ns`` (n,) header stamps (ns); ``position`` (n, 3) m and ``orientation`` (n, 4)
    quaternions x y z w, in whatever frame ``frame_id`` names. ``encoding`` ``cdr`` (ROS 2,
    with the encapsulation header) or ``ros1`` (header ``seq`` 0, as rosbags writes a message
    whose seq is 0). Byte-identical to rosbags' ``serialize_cdr`` / ``serialize_ros1`` of each
    message (tests/test_recorder_blocks.py checks it), built with numpy for the whole block.
    """
    t = np.asarray(stamps_ns, dtype=np.int64).reshape(-1)
    n = t.size
    p = np.asarray(position, dtype=np.float64).reshape(n, 3)
    q = np.asarray(orientation, dtype=np.float64).reshape(n, 4)
    head, at = _head_template(frame_id, encoding, 1 if encoding == "ros1" else 8)
    sec, nsec = _stamp_fields(t, encoding, f"PoseStamped {frame_id!r}")
    width = len(head) + 56
    rows = np.empty((n, width), dtype=np.uint8)
    rows[:, : len(head)] = np.frombuffer(head, dtype=np.uint8)
    _fill_stamps(rows, sec, nsec, at, encoding)
    vals = np.empty((n, 7), dtype="<f8")
    vals[:, :3] = p
    vals[:, 3:] = q
    rows[:, len(head) :] = vals.view(np.uint8).reshape(n, 56)
    return rows


def encode_header_block(stamps_ns: I64, frame_id: str, encoding: str = "cdr") -> U8:
    """A block of std_msgs/Header bodies stamped ``stamps_ns`` (ns), one row each; as
    :func:`encode_pose_block` (byte-identical to rosbags' serializers)."""
    t = np.asarray(stamps_ns, dtype=np.int64).reshape(-1)
    head, at = _head_template(frame_id, encoding, 1)
    sec, nsec = _stamp_fields(t, encoding, f"Header {frame_id!r}")
    rows = np.empty((t.size, len(head)), dtype=np.uint8)
    rows[:] = np.frombuffer(head, dtype=np.uint8)
    _fill_stamps(rows, sec, nsec, at, encoding)
    return rows


@dataclass(frozen=True)
class RawBlock:
    """Serialized messages of one topic, in the order they were written.

    ``rows`` (n, width) uint8 message bodies; ``log_times`` (n,) ns; ``ranks`` (n,) the
    position of each message in the whole batch (all blocks of one write, 0..N-1), which is
    the order the per-message path would have written them in.
    """

    topic: str
    msgtype: str
    rows: U8
    log_times: I64
    ranks: I64


def write_raw_blocks(writer: Any, blocks: list[RawBlock]) -> None:
    """Write ``blocks`` through ``writer``: one call of its ``write_blocks`` when it has one
    (:class:`McapBlockWriter`), else message by message through ``write_raw`` in rank order
    (rosbags' writers), so both give the same messages in the same order."""
    if not blocks:
        return
    batch = getattr(writer, "write_blocks", None)
    if batch is not None:
        batch(blocks)
        return
    total = sum(len(b.ranks) for b in blocks)
    which = np.empty(total, dtype=np.int64)
    index = np.empty(total, dtype=np.int64)
    for i, b in enumerate(blocks):
        which[b.ranks] = i
        index[b.ranks] = np.arange(len(b.ranks))
    raw = writer.write_raw
    for i, k in zip(which.tolist(), index.tolist(), strict=True):
        b = blocks[i]
        raw(b.topic, b.msgtype, b.rows[k].tobytes(), int(b.log_times[k]))


class OneMessageWrites:
    """The per-message writes of a block writer (the recorder's writer interface), each a
    block of one message: the writer implements only ``write_blocks`` and names its
    ``encoding`` ("cdr" for MCAP, "ros1" for ROS 1 bags)."""

    encoding = "cdr"

    def write_blocks(self, blocks: list[RawBlock]) -> None:
        raise NotImplementedError

    def _one(self, topic: str, msgtype: str, rows: U8, log_time: int) -> None:
        self.write_blocks(
            [RawBlock(topic, msgtype, rows, np.array([int(log_time)]), np.zeros(1, np.int64))]
        )

    def write_raw(
        self, topic: str, msgtype: str, data: bytes, log_time: int, publish_time: int | None = None
    ) -> None:
        """Write one message already serialized in the writer's encoding (``publish_time``
        is the log time)."""
        rows = np.frombuffer(bytes(data), dtype=np.uint8).reshape(1, -1)
        self._one(topic, msgtype, rows, log_time)

    def write_pose(
        self,
        topic: str,
        t_ns: int,
        position: F64,
        quat: F64,
        frame_id: str,
        log_time: int | None = None,
    ) -> None:
        """Write one PoseStamped stamped ``t_ns`` (header) and logged at ``log_time``."""
        rows = encode_pose_block(np.array([int(t_ns)]), position, quat, frame_id, self.encoding)
        self._one(topic, POSE_STAMPED, rows, int(t_ns) if log_time is None else int(log_time))

    def write_header(self, topic: str, stamp_ns: int, log_time: int, frame_id: str = "") -> None:
        """Write one std_msgs/Header stamped ``stamp_ns`` and logged at ``log_time``."""
        rows = encode_header_block(np.array([int(stamp_ns)]), frame_id, self.encoding)
        self._one(topic, HEADER, rows, log_time)
