"""Pose log writers: MCAP (default), rosbag2 (sqlite3 or MCAP storage) and ROS 1 bag.

All writers share :class:`PoseLogWriter`'s methods, so the bridge's recorder can write any
format incrementally. rosbag2 and ROS 1 bags are written with rosbags' writers; payloads
are encoded by :mod:`uwval.io.encode` (vectorised) or rosbags (per message).
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from types import TracebackType
from typing import Any, Protocol

import numpy as np
from numpy.typing import NDArray

from uwval.errors import LogWriteError
from uwval.io.encode import encode_header, encode_pose_stamped
from uwval.io.mcap_io import McapPoseWriter
from uwval.io.ros import APPLIED_SUFFIX, HEADER, POSE_STAMPED, header_msg, pose_stamped, typestore
from uwval.posestream import PoseStream

F64 = NDArray[np.float64]

FORMATS = ("mcap", "rosbag2", "rosbag2-sqlite3", "rosbag2-mcap", "rosbag1")


class PoseLogWriter(Protocol):
    """What every uwval log writer offers (``McapPoseWriter``'s methods)."""

    encoding: str

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

    def write_raw(
        self, topic: str, msgtype: str, data: bytes, log_time: int, publish_time: int | None = None
    ) -> None: ...

    def flush(self) -> None: ...

    def close(self) -> None: ...

    def __enter__(self) -> Any: ...

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None: ...


class _RosbagsWriter:
    """Common part of the rosbag2 and ROS 1 writers (connections by topic, raw writes)."""

    encoding = "cdr"

    def __init__(self, path: Path) -> None:
        self.path = path
        self._writer: Any = None
        self._conns: dict[str, Any] = {}
        self._closed = False

    def _add_connection(self, topic: str, msgtype: str) -> Any:
        raise NotImplementedError

    def write_raw(
        self, topic: str, msgtype: str, data: bytes, log_time: int, publish_time: int | None = None
    ) -> None:
        """Write one message already serialized in this writer's ``encoding``."""
        conn = self._conns.get(topic)
        if conn is None:
            conn = self._conns[topic] = self._add_connection(topic, msgtype)
        try:
            self._writer.write(conn, int(log_time), data)
        except Exception as exc:
            raise LogWriteError(f"{self.path}: cannot write to {topic}: {exc}") from exc

    def _ros(self) -> int:
        return 1 if self.encoding == "ros1" else 2

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
        ros = self._ros()
        msg = pose_stamped(t_ns, position, quat, frame_id, ros_version=ros)
        ts = typestore(ros)
        data = (
            ts.serialize_ros1(msg, POSE_STAMPED)
            if ros == 1
            else ts.serialize_cdr(msg, POSE_STAMPED)
        )
        self.write_raw(topic, POSE_STAMPED, bytes(data), t_ns if log_time is None else log_time)

    def write_header(self, topic: str, stamp_ns: int, log_time: int, frame_id: str = "") -> None:
        """Write one std_msgs/Header (the Unity side's applied Gazebo stamps)."""
        ros = self._ros()
        msg = header_msg(stamp_ns, frame_id, ros_version=ros)
        ts = typestore(ros)
        data = ts.serialize_ros1(msg, HEADER) if ros == 1 else ts.serialize_cdr(msg, HEADER)
        self.write_raw(topic, HEADER, bytes(data), log_time)

    def flush(self) -> None:
        """Nothing to push: ROS 1 bags are indexed by ``close()`` (a killed recording is
        recovered by a linear walk, see :mod:`uwval.io.bag1_raw`)."""

    def close(self) -> None:
        if not self._closed:
            self._closed = True
            try:
                self._writer.close()
            except Exception as exc:
                raise LogWriteError(f"{self.path}: cannot finish log: {exc}") from exc

    def __enter__(self) -> Any:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()


class Rosbag2PoseWriter(_RosbagsWriter):
    """A rosbag2 directory (metadata.yaml + one storage file), sqlite3 or MCAP storage."""

    def __init__(
        self, path: str | Path, *, storage: str = "sqlite3", metadata: dict[str, str] | None = None
    ) -> None:
        from rosbags.rosbag2 import Writer
        from rosbags.rosbag2.enums import StoragePlugin

        super().__init__(Path(path))
        if self.path.exists():
            raise LogWriteError(f"{self.path}: exists; rosbag2 writes a new directory")
        plugin = {"sqlite3": StoragePlugin.SQLITE3, "mcap": StoragePlugin.MCAP}.get(storage)
        if plugin is None:
            raise LogWriteError(f"{self.path}: unknown rosbag2 storage {storage!r}")
        try:
            self._writer = Writer(self.path, version=9, storage_plugin=plugin)
            if metadata:
                for k, v in metadata.items():
                    self._writer.set_custom_data(f"uwval.{k}", str(v))
            self._writer.open()
        except Exception as exc:
            raise LogWriteError(f"{self.path}: cannot create rosbag2: {exc}") from exc

    def _add_connection(self, topic: str, msgtype: str) -> Any:
        return self._writer.add_connection(topic, msgtype, typestore=typestore(2))

    def flush(self) -> None:
        """Commit the messages written so far (sqlite3 storage), so that a recorder killed
        later leaves them readable (the directory then lacks metadata.yaml; uwval reads the
        .db3 alone). MCAP storage is finished by ``close()`` only."""
        conn = getattr(getattr(self._writer, "storage", None), "conn", None)
        if conn is not None:
            conn.commit()


class Rosbag1PoseWriter(_RosbagsWriter):
    """A ROS 1 bag (v2.0, uncompressed chunks), readable by ROS 1's own rosbag.

    ``metadata`` is stored as one std_msgs/String JSON message on ``/uwval/metadata``
    (ROS 1 bags have no metadata records).
    """

    encoding = "ros1"

    def __init__(self, path: str | Path, *, metadata: dict[str, str] | None = None) -> None:
        from rosbags.rosbag1 import Writer

        super().__init__(Path(path))
        try:
            self._writer = Writer(self.path)
            self._writer.open()
        except Exception as exc:
            raise LogWriteError(f"{self.path}: cannot create ROS 1 bag: {exc}") from exc
        if metadata:
            ts = typestore(1)
            msg = ts.types["std_msgs/msg/String"](data=json.dumps(metadata))
            self.write_raw(
                "/uwval/metadata",
                "std_msgs/msg/String",
                bytes(ts.serialize_ros1(msg, "std_msgs/msg/String")),
                0,
            )

    def _add_connection(self, topic: str, msgtype: str) -> Any:
        return self._writer.add_connection(topic, msgtype, typestore=typestore(1))


def open_writer(
    path: str | Path, format: str = "mcap", metadata: dict[str, str] | None = None
) -> PoseLogWriter:
    """A pose log writer for ``format``: ``mcap`` (default), ``rosbag2`` / ``rosbag2-sqlite3``
    (directory, sqlite3 storage), ``rosbag2-mcap`` (directory, MCAP storage) or ``rosbag1``.

    Writers are incremental (write as you go, ``flush()``, ``close()``) and context managers.
    """
    p = Path(path)
    if format != "mcap" and format in (*FORMATS, "bag"):
        _clear_old_log(p)
    if format == "mcap":
        return McapPoseWriter(p, metadata=metadata)
    if format in ("rosbag2", "rosbag2-sqlite3"):
        return Rosbag2PoseWriter(p, storage="sqlite3", metadata=metadata)
    if format == "rosbag2-mcap":
        return Rosbag2PoseWriter(p, storage="mcap", metadata=metadata)
    if format in ("rosbag1", "bag"):
        return Rosbag1PoseWriter(p, metadata=metadata)
    raise LogWriteError(f"{p}: unknown log format {format!r}; choose one of {', '.join(FORMATS)}")


def write_stream(
    writer: PoseLogWriter,
    topic: str,
    stream: PoseStream,
    frame_id: str,
    *,
    log_time: NDArray[np.int64] | None = None,
) -> int:
    """Write a whole PoseStream as PoseStamped on ``topic`` (vectorised encode).

    Positions and orientations are written as stored (in ``stream.frame``'s axes); the
    header stamp is ``stream.t`` and the log time ``log_time`` (default ``stream.t``). When
    ``stream.applied_stamp`` is set, the ``<topic>/applied_stamp`` Header companion is
    written too. Returns the number of messages written.
    """
    enc = getattr(writer, "encoding", "cdr")
    lt = stream.t if log_time is None else np.asarray(log_time, dtype=np.int64)
    rows = encode_pose_stamped(stream.t, stream.position, stream.orientation, frame_id, enc)
    lt_list = lt.tolist()
    for i in range(rows.shape[0]):
        writer.write_raw(topic, POSE_STAMPED, rows[i].tobytes(), lt_list[i])
    n = rows.shape[0]
    if stream.applied_stamp is not None:
        hdr = encode_header(stream.applied_stamp, "world", enc)
        for i in range(hdr.shape[0]):
            writer.write_raw(topic + APPLIED_SUFFIX, HEADER, hdr[i].tobytes(), lt_list[i])
        n += hdr.shape[0]
    return int(n)


def _clear_old_log(p: Path) -> None:
    """Replace an earlier log at ``p`` as the MCAP writer does (rosbags refuses to).

    Only files and directories that hold nothing but a rosbag2's own files are removed.
    """
    if p.is_file():
        p.unlink()
    elif p.is_dir():
        names = [c.name for c in p.iterdir()]
        own = all(
            n == "metadata.yaml" or n.endswith((".db3", ".mcap", ".db3-wal", ".db3-shm", ".zstd"))
            for n in names
        )
        if names and own and "metadata.yaml" in names:
            shutil.rmtree(p)
