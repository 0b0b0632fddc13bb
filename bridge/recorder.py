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

from uwval.frames import get_convention
from uwval.io.ros import APPLIED_SUFFIX

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


class BridgeRecorder:
    """Write Gazebo-side and Unity-side poses of one run through ``writer``.

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
        #: Messages written per topic (applied_stamp companions included).
        self.written: dict[str, int] = {}
        #: Messages per topic as of the last flush (what survives a SIGKILL).
        self.flushed: dict[str, int] = {}
        self._since_flush = 0
        self._last_flush = time.monotonic()
        self.closed = False

    def _count(self, topic: str) -> None:
        self.written[topic] = self.written.get(topic, 0) + 1
        self._since_flush += 1
        if (self.flush_every and self._since_flush >= self.flush_every) or (
            time.monotonic() - self._last_flush >= self.flush_interval_s
        ):
            self.flush()

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
        topic = log_topic(GAZEBO_PREFIX, name)
        self.writer.write_pose(
            topic,
            int(t_ns),
            position,
            quat,
            frame_id,
            int(t_ns) if log_time is None else int(log_time),
        )
        self._count(topic)

    def unity_pose(
        self, name: str, unity_t_ns: int, position: F64, quat: F64, applied_stamp_ns: int
    ) -> None:
        """One Unity frame's transform (Unity axes, Unity clock) and its applied stamp, on
        ``/unity/<name>`` (absolute names kept, see :func:`log_topic`)."""
        topic = log_topic(UNITY_PREFIX, name)
        self.writer.write_pose(
            topic, int(unity_t_ns), position, quat, self.unity_map, int(unity_t_ns)
        )
        self._count(topic)
        self.writer.write_header(
            topic + APPLIED_SUFFIX, int(applied_stamp_ns), int(unity_t_ns), GAZEBO_FRAME_ID
        )
        self._count(topic + APPLIED_SUFFIX)

    def flush(self) -> None:
        """Push everything written so far to the file (finishing the open MCAP chunk)."""
        flush = getattr(self.writer, "flush", None)
        if flush is not None:
            flush()
        self.flushed = dict(self.written)
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
) -> Any:
    """An :class:`~uwval.io.mcap_io.McapPoseWriter` for a recorder (64 KiB chunks, so that
    a crash loses little; its ``flush()`` finishes the open chunk)."""
    from uwval.io.mcap_io import McapPoseWriter

    return McapPoseWriter(path, metadata=metadata, chunk_size=chunk_size)


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
