"""Pose log writers, the one writer stack: MCAP (default), rosbag2 (sqlite3 or MCAP storage)
and ROS 1 bag.

Every writer takes messages one by one (``write_pose``, ``write_header``, ``write_raw``) or
as blocks of serialized messages (``write_blocks``, :class:`RawBlock`: what the bridge's
recorder hands over), encoded by :mod:`uwval.io.encode` with numpy. MCAP and ROS 1 bags are
written by uwval (:class:`McapPoseWriter`: the bytes mcap's own writer writes, a block's
records built at once); ROS 1 bags and rosbag2 by rosbags' writers.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from uwval.errors import LogWriteError
from uwval.io.encode import encode_header, encode_pose_stamped
from uwval.io.mcap_io import McapPoseWriter, OneMessageWrites, RawBlock
from uwval.io.ros import APPLIED_SUFFIX, HEADER, POSE_STAMPED, typestore
from uwval.posestream import PoseStream

F64 = NDArray[np.float64]
I64 = NDArray[np.int64]

FORMATS = ("mcap", "rosbag2", "rosbag2-sqlite3", "rosbag2-mcap", "rosbag1")

__all__ = [
    "FORMATS",
    "McapPoseWriter",
    "PoseLogWriter",
    "RawBlock",
    "Rosbag1PoseWriter",
    "Rosbag2PoseWriter",
    "open_writer",
    "write_stream",
]


#: What every uwval log writer offers: one-by-one writes, ``write_blocks``, ``flush``,
#: ``close``, a context manager, the payload ``encoding`` (``cdr`` or ``ros1``).
PoseLogWriter = OneMessageWrites


def in_rank_order(blocks: list[RawBlock]) -> list[tuple[RawBlock, int]]:
    """(block, row) of every message of ``blocks``, in the order they were written."""
    total = sum(len(b.ranks) for b in blocks)
    which, index = np.empty(total, dtype=np.int64), np.empty(total, dtype=np.int64)
    for i, b in enumerate(blocks):
        which[b.ranks] = i
        index[b.ranks] = np.arange(len(b.ranks))
    return [(blocks[i], k) for i, k in zip(which.tolist(), index.tolist(), strict=True)]


class _RosbagsWriter(OneMessageWrites):
    """A log written by rosbags' writer (``writer``: a ``rosbag1`` or ``rosbag2`` Writer, not
    yet opened), message by message."""

    def __init__(self, path: Path, make: Any, ros: int) -> None:
        self.path, self._ros = path, ros
        self._conns: dict[str, Any] = {}
        self._closed = False
        try:
            self._writer = make()
            self._writer.open()
        except Exception as exc:
            what = "ROS 1 bag" if ros == 1 else "rosbag2"
            raise LogWriteError(f"{path}: cannot create {what}: {exc}") from exc

    def write_blocks(self, blocks: list[RawBlock]) -> None:
        """Write the messages of ``blocks`` one by one, in the order they came."""
        for b in blocks:  # rosbags would fail only when it writes the index, at close
            t = np.asarray(b.log_times)
            if self._ros == 1 and t.size and (t.min() < 0 or t.max() // 10**9 >= 2**32):
                raise LogWriteError(f"{self.path}: {b.topic}: log time outside ROS 1 time")
        for b, k in in_rank_order(blocks):
            conn = self._conns.get(b.topic)
            if conn is None:
                conn = self._conns[b.topic] = self._add_connection(b.topic, b.msgtype)
            try:
                self._writer.write(conn, int(b.log_times[k]), b.rows[k].tobytes())
            except Exception as exc:
                raise LogWriteError(f"{self.path}: cannot write to {b.topic}: {exc}") from exc

    def _add_connection(self, topic: str, msgtype: str) -> Any:
        return self._writer.add_connection(topic, msgtype, typestore=typestore(self._ros))

    def flush(self) -> None:
        """rosbag2 with sqlite3 storage: commit what was written (a recorder killed later
        leaves it readable; uwval reads the .db3 alone). A ROS 1 bag and MCAP storage are
        finished by ``close()`` (a killed ROS 1 recording is recovered by a linear walk)."""
        conn = getattr(getattr(self._writer, "storage", None), "conn", None)
        if conn is not None:
            conn.commit()

    def close(self) -> None:
        if not self._closed:
            self._closed = True
            try:
                self._writer.close()
            except Exception as exc:
                raise LogWriteError(f"{self.path}: cannot finish log: {exc}") from exc


class Rosbag2PoseWriter(_RosbagsWriter):
    """A rosbag2 directory (metadata.yaml + one storage file), sqlite3 or MCAP storage."""

    def __init__(
        self, path: str | Path, *, storage: str = "sqlite3", metadata: dict[str, str] | None = None
    ) -> None:
        from rosbags.rosbag2 import Writer
        from rosbags.rosbag2.enums import StoragePlugin

        p = Path(path)
        if p.exists():
            raise LogWriteError(f"{p}: exists; rosbag2 writes a new directory")
        plugin = {"sqlite3": StoragePlugin.SQLITE3, "mcap": StoragePlugin.MCAP}.get(storage)
        if plugin is None:
            raise LogWriteError(f"{p}: unknown rosbag2 storage {storage!r}")

        def make() -> Any:
            writer = Writer(p, version=9, storage_plugin=plugin)
            for k, v in (metadata or {}).items():
                writer.set_custom_data(f"uwval.{k}", str(v))
            return writer

        super().__init__(p, make, 2)


class Rosbag1PoseWriter(_RosbagsWriter):
    """A ROS 1 bag (v2.0, uncompressed chunks), readable by ROS 1's own rosbag. ``metadata``
    is one std_msgs/String JSON message on ``/uwval/metadata`` (ROS 1 bags have no metadata
    records)."""

    encoding = "ros1"

    def __init__(self, path: str | Path, *, metadata: dict[str, str] | None = None) -> None:
        from rosbags.rosbag1 import Writer

        super().__init__(Path(path), lambda: Writer(Path(path)), 1)
        if metadata:
            ts = typestore(1)
            msg = ts.types["std_msgs/msg/String"](data=json.dumps(metadata))
            data = bytes(ts.serialize_ros1(msg, "std_msgs/msg/String"))
            self.write_raw("/uwval/metadata", "std_msgs/msg/String", data, 0)


def open_writer(
    path: str | Path,
    format: str = "mcap",
    metadata: dict[str, str] | None = None,
    chunk_size: int = 256 * 1024,
) -> PoseLogWriter:
    """A pose log writer for ``format``: ``mcap`` (default; ``chunk_size`` bytes per chunk),
    ``rosbag2`` / ``rosbag2-sqlite3`` (directory, sqlite3 storage), ``rosbag2-mcap``
    (directory, MCAP storage) or ``rosbag1``. An earlier log at ``path`` is replaced.

    Writers are incremental (write as you go, ``flush()``, ``close()``) and context managers.
    """
    p = Path(path)
    if format != "mcap" and format in (*FORMATS, "bag"):
        _clear_old_log(p)
    if format == "mcap":
        return McapPoseWriter(p, metadata=metadata, chunk_size=chunk_size)
    if format in ("rosbag2", "rosbag2-sqlite3", "rosbag2-mcap"):
        storage = "mcap" if format == "rosbag2-mcap" else "sqlite3"
        return Rosbag2PoseWriter(p, storage=storage, metadata=metadata)
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
    """Write a whole PoseStream as PoseStamped on ``topic`` (vectorised encode, one block).

    Positions and orientations are written as stored (in ``stream.frame``'s axes); the
    header stamp is ``stream.t`` and the log time ``log_time`` (default ``stream.t``). When
    ``stream.applied_stamp`` is set, the ``<topic>/applied_stamp`` Header companion is
    written too. Returns the number of messages written.
    """
    enc = getattr(writer, "encoding", "cdr")
    lt = stream.t if log_time is None else np.asarray(log_time, dtype=np.int64)
    parts = [
        (
            topic,
            POSE_STAMPED,
            encode_pose_stamped(stream.t, stream.position, stream.orientation, frame_id, enc),
        )
    ]
    if stream.applied_stamp is not None:
        hdr = encode_header(stream.applied_stamp, "world", enc)
        parts.append((topic + APPLIED_SUFFIX, HEADER, hdr))
    for name, msgtype, rows in parts:  # in slices of about a chunk (256 KiB) each
        step = max(1, (256 * 1024) // rows.shape[1])
        for i in range(0, rows.shape[0], step):
            k = min(step, rows.shape[0] - i)
            writer.write_blocks(
                [RawBlock(name, msgtype, rows[i : i + k], lt[i : i + k], np.arange(k))]
            )
    return sum(p[2].shape[0] for p in parts)


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
