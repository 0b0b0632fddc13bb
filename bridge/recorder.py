"""Record both sides of a bridged run into one log, incrementally.

Topics (DESIGN.md section 4, issue 2 item 6):

- ``/gazebo/model_rov_pose``, ``/gazebo/gui_camera_pose``: PoseStamped in ENU world / FLU
  body, ``frame_id`` ``"world"``, header stamp = sim time.
- ``/unity/model_rov_pose``, ``/unity/gui_camera_pose``: PoseStamped in Unity axes; the
  header ``frame_id`` is the convention name (``unity-flu`` / ``unity-enu``) so readers know
  the map; header stamp = Unity's clock.
- ``/unity/<name>/applied_stamp``: std_msgs/Header per Unity frame whose stamp is the Gazebo
  header stamp that frame applied (``uwval.io.read_stream`` attaches it as ``applied_stamp``).

The writer is anything with the interface of :class:`uwval.io.mcap_io.McapPoseWriter`.
The recorder flushes every ``flush_every`` messages and every ``flush_interval_s`` wall
seconds, so a SIGKILL loses at most what came after the last flush; :meth:`close` writes
everything (a clean stop loses nothing).
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import numpy as np
from numpy.typing import NDArray

from uwval.errors import LogWriteError
from uwval.frames import get_convention
from uwval.io.encode import encode_header, encode_pose_stamped
from uwval.io.ros import APPLIED_SUFFIX, HEADER, POSE_STAMPED
from uwval.io.writers import McapPoseWriter, PoseLogWriter, RawBlock, open_writer

__all__ = [
    "GAZEBO_FRAME_ID",
    "GAZEBO_PREFIX",
    "UNITY_PREFIX",
    "BridgeRecorder",
    "PoseWriter",
    "RecoveryReport",
    "log_topic",
    "open_log_writer",
    "open_mcap_writer",
    "scan_mcap",
]

F64 = NDArray[np.float64]

GAZEBO_PREFIX = "/gazebo"
UNITY_PREFIX = "/unity"
GAZEBO_FRAME_ID = "world"


def log_topic(prefix: str, name: str) -> str:
    """The recorded topic of ``name``: an absolute name (``/gazebo/model_rov_pose``) is kept
    as it is; a relative one goes under ``prefix`` (``model_rov_pose`` ->
    ``/gazebo/model_rov_pose``). Never a double slash."""
    if name.startswith("/"):
        return "/" + "/".join(p for p in name.split("/") if p)
    return "/".join([prefix.rstrip("/"), *(p for p in name.split("/") if p)])


class PoseWriter(Protocol):
    """What the recorder needs from a log writer (McapPoseWriter's interface)."""

    def write_pose(
        self,
        topic: str,
        t_ns: int,
        position: F64,
        quat: F64,
        frame_id: str,
        log_time: int | None = None,
    ) -> None: ...

    def write_header(
        self, topic: str, stamp_ns: int, log_time: int, frame_id: str = ""
    ) -> None: ...

    def close(self) -> None: ...


class _Pending:
    """Messages of one topic waiting for the next flush (columns, not message objects)."""

    __slots__ = ("frame_id", "logs", "msgtype", "pos", "quat", "ranks", "stamps", "topic")

    def __init__(self, topic: str, msgtype: str, frame_id: str) -> None:
        self.topic = topic
        self.msgtype = msgtype
        self.frame_id = frame_id
        self.clear()

    def clear(self) -> None:
        self.stamps: list[int] = []
        self.logs: list[int] = []
        self.ranks: list[int] = []
        self.pos: list[Any] = []
        self.quat: list[Any] = []

    def add(self, stamp: int, log: int, rank: int, position: Any = None, quat: Any = None) -> None:
        """One message: header stamp and log time (ns), its rank in the run; a pose's
        position and orientation (a Header has none)."""
        self.stamps.append(stamp)
        self.logs.append(log)
        self.ranks.append(rank)
        if position is not None:
            self.pos.append(position)
            self.quat.append(quat)


class BridgeRecorder:
    """Write Gazebo-side and Unity-side poses of one run through ``writer``.

    With a writer that takes blocks of serialized messages (``write_blocks``: uwval's log
    writers, :mod:`uwval.io.writers`) the recorder keeps the messages since the last flush
    as columns and, at each flush, encodes every topic's block at once with numpy
    (:mod:`uwval.io.encode`, in the writer's ``encoding``) and hands the blocks over in one
    call: the same messages, bytes and order as writing each at once, without a Python
    serialization per message. Any other :class:`PoseWriter` gets
    ``write_pose``/``write_header`` per message as they come.

    Args:
        writer: a :class:`PoseWriter`; its ``flush()`` (when present) is called at each flush.
        unity_map: the ROS-TCP-Connector map of the Unity poses (goes into frame_id).
        flush_every: flush after this many messages (0: only by time and at close).
        flush_interval_s: flush when this many wall seconds passed since the last flush.
    """

    def __init__(
        self,
        writer: PoseWriter,
        *,
        unity_map: str = "unity-flu",
        flush_every: int = 1000,
        flush_interval_s: float = 0.5,
    ) -> None:
        self.writer = writer
        self.unity_map = get_convention(unity_map).name
        self.flush_every = int(flush_every)
        self.flush_interval_s = float(flush_interval_s)
        self._flush_at = self.flush_every if self.flush_every > 0 else 2**62
        #: Messages per topic as of the last flush (what survives a SIGKILL).
        self.flushed: dict[str, int] = {}
        self._counted: dict[str, int] = {}  # messages per topic not in pending buffers
        self._since_flush = 0
        self._last_flush = time.monotonic()
        self.closed = False
        #: Messages are encoded in blocks at each flush (the writer takes raw bytes).
        self.blocks = callable(getattr(writer, "write_blocks", None))
        self.encoding = str(getattr(writer, "encoding", "cdr"))
        self._pending: dict[str, _Pending] = {}
        self._rank = 0
        self._topics: dict[tuple[str, str], str] = {}
        # per (prefix, name, frame_id): the topic's pending buffer (and applied-stamp buffer)
        self._gz: dict[tuple[str, str], _Pending] = {}
        self._un: dict[str, tuple[_Pending, _Pending]] = {}
        self._warm_up()

    def _warm_up(self) -> None:
        """Set up now what the first flush would (rosbags' type store and message
        definitions, the chunk compressor: ~0.3-0.5 s), so that it does not happen on a live
        render loop's thread and hold up the frames of the first second."""
        import zstandard

        from uwval.io.ros import typestore

        ros = 1 if self.encoding == "ros1" else 2
        for msgtype in (POSE_STAMPED, HEADER):
            typestore(ros).generate_msgdef(msgtype, ros_version=ros)
        zstandard.ZstdCompressor()

    @property
    def written(self) -> dict[str, int]:
        """Messages written per topic (applied_stamp companions included), flushed or not."""
        out = dict(self._counted)
        for topic, buf in self._pending.items():
            if buf.ranks:
                out[topic] = out.get(topic, 0) + len(buf.ranks)
        return out

    def _topic(self, prefix: str, name: str) -> str:
        key = (prefix, name)
        topic = self._topics.get(key)
        if topic is None:
            topic = self._topics[key] = log_topic(prefix, name)
        return topic

    def _count(self, topic: str) -> None:
        """One message went to the writer as it came (the per-message path)."""
        self._counted[topic] = self._counted.get(topic, 0) + 1
        self._tick()

    def _tick(self) -> None:
        self._since_flush += 1
        if (
            self._since_flush >= self._flush_at
            or time.monotonic() - self._last_flush >= self.flush_interval_s
        ):
            self.flush()

    def _buffer(self, topic: str, msgtype: str, frame_id: str) -> _Pending:
        buf = self._pending.get(topic)
        if buf is None or buf.frame_id != frame_id or buf.msgtype != msgtype:
            if buf is not None and buf.ranks:  # the topic's frame changed: earlier ones first
                self._write_pending()
            buf = self._pending[topic] = _Pending(topic, msgtype, frame_id)
            self._gz.clear()
            self._un.clear()
        return buf

    def gazebo_pose(
        self,
        name: str,
        t_ns: int,
        position: F64,
        quat: F64,
        log_time: int | None = None,
        frame_id: str = GAZEBO_FRAME_ID,
    ) -> None:
        """One Gazebo pose (ENU world / FLU body, header stamp ``t_ns`` ns: sim time, or the
        ROS epoch stamp received) on ``/gazebo/<name>`` (absolute names kept, see
        :func:`log_topic`)."""
        t = int(t_ns)
        log = t if log_time is None else int(log_time)
        if not self.blocks:
            topic = self._topic(GAZEBO_PREFIX, name)
            self.writer.write_pose(topic, t, position, quat, frame_id, log)
            self._count(topic)
            return
        buf = self._gz.get((name, frame_id))
        if buf is None:
            buf = self._gz[(name, frame_id)] = self._buffer(
                self._topic(GAZEBO_PREFIX, name), POSE_STAMPED, frame_id
            )
        buf.add(t, log, self._rank, position, quat)
        self._rank += 1
        self._tick()

    def unity_pose(
        self, name: str, unity_t_ns: int, position: F64, quat: F64, applied_stamp_ns: int
    ) -> None:
        """One Unity frame's transform (Unity axes, Unity clock) and its applied stamp, on
        ``/unity/<name>`` (absolute names kept, see :func:`log_topic`)."""
        t = int(unity_t_ns)
        if not self.blocks:
            topic = self._topic(UNITY_PREFIX, name)
            self.writer.write_pose(topic, t, position, quat, self.unity_map, t)
            self._count(topic)
            self.writer.write_header(
                topic + APPLIED_SUFFIX, int(applied_stamp_ns), t, GAZEBO_FRAME_ID
            )
            self._count(topic + APPLIED_SUFFIX)
            return
        bufs = self._un.get(name)
        if bufs is None:
            topic = self._topic(UNITY_PREFIX, name)
            pose = self._buffer(topic, POSE_STAMPED, self.unity_map)
            bufs = self._un[name] = (
                pose,
                self._buffer(topic + APPLIED_SUFFIX, HEADER, GAZEBO_FRAME_ID),
            )
        pose, applied = bufs
        pose.add(t, t, self._rank, position, quat)
        self._rank += 1
        self._tick()  # may flush between the pose and its stamp, as message by message
        applied.add(int(applied_stamp_ns), t, self._rank)
        self._rank += 1
        self._tick()

    def _write_pending(self) -> None:
        """Encode every topic's pending block and write them, in the order they came."""
        blocks = []
        for topic, buf in self._pending.items():
            n = len(buf.ranks)
            if not n:
                continue
            stamps = np.array(buf.stamps, dtype=np.int64)
            if buf.msgtype == HEADER:
                rows = encode_header(stamps, buf.frame_id, self.encoding)
            else:
                try:
                    pos = np.array(buf.pos, dtype=np.float64).reshape(-1, 3)
                    quat = np.array(buf.quat, dtype=np.float64).reshape(-1, 4)
                    if pos.shape[0] != n or quat.shape[0] != n:
                        raise ValueError("one position (3) and one quaternion (4) per pose")
                except ValueError as exc:
                    buf.clear()
                    raise LogWriteError(
                        f"{topic}: a pose is not 3 position numbers and 4 quaternion numbers "
                        f"({exc})"
                    ) from None
                rows = encode_pose_stamped(stamps, pos, quat, buf.frame_id, self.encoding)
            blocks.append(
                RawBlock(
                    topic,
                    buf.msgtype,
                    rows,
                    np.array(buf.logs, dtype=np.int64),
                    np.array(buf.ranks, dtype=np.int64),
                )
            )
            self._counted[topic] = self._counted.get(topic, 0) + n
            buf.clear()
        self._rank = 0
        if blocks:
            self.writer.write_blocks(blocks)  # type: ignore[attr-defined]

    def flush(self) -> None:
        """Push everything written so far to the file (finishing the open MCAP chunk)."""
        self._write_pending()
        flush = getattr(self.writer, "flush", None)
        if flush is not None:
            flush()
        self.flushed = dict(self._counted)
        self._since_flush = 0
        self._last_flush = time.monotonic()

    def close(self) -> None:
        """Flush and close the writer (idempotent)."""
        if not self.closed:
            self.flush()
            self.writer.close()
            self.closed = True


def open_mcap_writer(
    path: str | Path, *, metadata: dict[str, str] | None = None, chunk_size: int = 64 * 1024
) -> McapPoseWriter:
    """An MCAP writer for a live recorder (64 KiB chunks, so that a crash loses little; its
    ``flush()`` finishes the open chunk)."""
    return McapPoseWriter(path, metadata=metadata, chunk_size=chunk_size)


def open_log_writer(
    path: str | Path, format: str = "mcap", metadata: dict[str, str] | None = None
) -> PoseLogWriter:
    """The log writer of a recorded run (:func:`uwval.io.writers.open_writer`)."""
    return open_writer(path, format=format, metadata=metadata)


@dataclass(frozen=True)
class RecoveryReport:
    """What a (possibly truncated or damaged) MCAP log still holds.

    ``messages`` per topic readable; ``complete`` is True when the file ends with its footer
    (a clean stop) and every chunk passed its checks (CRC, index); ``lost_bytes`` are the
    trailing bytes cut off by a crash; ``error`` says what was found wrong.
    """

    path: str
    messages: dict[str, int]
    complete: bool
    valid_bytes: int
    total_bytes: int
    error: str = ""
    closed: bool = True  # False: no summary/footer (the writer was stopped before close)

    @property
    def lost_bytes(self) -> int:
        return self.total_bytes - self.valid_bytes

    def describe(self) -> str:
        """One line for users: what survived and what was cut off or damaged."""
        n = sum(self.messages.values())
        if self.complete:
            return f"{self.path}: complete, {n} messages"
        if self.lost_bytes or not self.closed:
            return (
                f"{self.path}: truncated after byte {self.valid_bytes} of {self.total_bytes}"
                f" ({self.lost_bytes} bytes of an unfinished record lost); {n} messages "
                f"recovered ({self.error})"
            )
        return f"{self.path}: not complete, {n} messages readable ({self.error})"


def scan_mcap(path: str | Path) -> RecoveryReport:
    """Scan an MCAP with uwval's log reader (every chunk decompressed and checked: CRC, index
    against records), counting messages per topic and tolerating truncation and damage.

    A recorder killed with SIGKILL leaves complete chunks up to its last flush followed by
    a partial record; this reports what is readable and how many bytes were cut off.
    """
    from uwval.io.mcap_raw import scan_mcap as scan_raw

    p = Path(path)
    total = p.stat().st_size
    log = scan_raw(p, None, times_only=True)
    problems = log.all_warnings()
    counts = {i.name: i.count for i in log.topics if i.count}
    return RecoveryReport(
        str(p),
        counts,
        not problems,
        total - log.lost_bytes,
        total,
        "; ".join(problems),
        not log.unclean,
    )
