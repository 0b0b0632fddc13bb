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

import struct
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import numpy as np
from numpy.typing import NDArray

from uwval.errors import LogWriteError
from uwval.frames import get_convention
from uwval.io.ros import APPLIED_SUFFIX, HEADER, POSE_STAMPED

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


# --------------------------------------------------------------------------- block encoding
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


# --------------------------------------------------------------------------- MCAP writer
_MSG_HEAD = 1 + 8 + 2 + 4 + 8 + 8  # opcode, record length, channel, sequence, log, publish


class McapBlockWriter:
    """An MCAP log writer that takes whole blocks of serialized messages (:class:`RawBlock`).

    The file is what :class:`uwval.io.mcap_io.McapPoseWriter` writes (profile ``ros2``,
    library ``uwval``, zstd chunks with CRCs and message indexes, ros2msg schemas generated by
    rosbags, channel metadata ``offered_qos_profiles``, per-channel sequence numbers from 0,
    metadata record ``uwval``, statistics, chunk and metadata indexes, summary offsets), but
    a block's Message records and message indexes are built with numpy at once instead of one
    ``add_message`` call per message (that call was ~40 % of ``uwval simulate``). The records
    around the messages are mcap's own record classes. Readable by the mcap library, its
    ros2 decoder and uwval's readers (tests/test_recorder_blocks.py).

    ``flush()`` finishes the open chunk and writes it (a killed process leaves every flushed
    chunk readable); a chunk is also finished when it exceeds ``chunk_size`` bytes.
    """

    encoding = "cdr"

    def __init__(
        self,
        path: str | Path,
        *,
        metadata: dict[str, str] | None = None,
        chunk_size: int = 256 * 1024,
    ) -> None:
        from mcap.data_stream import RecordBuilder
        from mcap.records import Header

        self.path = Path(path)
        try:
            self._fh = open(self.path, "wb")  # noqa: SIM115 - closed in close()
        except OSError as exc:
            raise LogWriteError(f"{self.path}: cannot open for writing: {exc}") from exc
        self.chunk_size = int(chunk_size)
        self._rb = RecordBuilder()
        self._schemas: dict[str, Any] = {}  # msgtype -> Schema record
        self._channels: dict[str, Any] = {}  # topic -> Channel record
        self._next_seq: dict[int, int] = {}
        self._counts: dict[int, int] = {}
        # schema/channel records for the open chunk: (slot, record); a channel's records go
        # just before its first message, as mcap's writer places them
        self._pending_defs: list[tuple[int, Any]] = []
        self._segments: list[tuple[int, U8, I64, I64]] = []  # channel, records, log, rank
        self._pending_bytes = 0
        self._pending_n = 0
        self._chunk_indexes: list[Any] = []
        self._metadata_indexes: list[Any] = []
        self._start = 0
        self._end = 0
        self._n = 0
        self._closed = False
        self._fh.write(_MCAP_MAGIC)
        Header(profile="ros2", library="uwval").write(self._rb)
        self._emit()
        if metadata:
            self.add_metadata("uwval", metadata)

    def add_metadata(self, name: str, data: dict[str, Any]) -> None:
        """Add an MCAP metadata record now (values stored as strings; others as JSON), before
        the open chunk, as mcap's writer does."""
        import json

        from mcap.records import Metadata, MetadataIndex

        if self._closed:
            raise LogWriteError(f"{self.path}: the log is closed")
        text = {k: v if isinstance(v, str) else json.dumps(v) for k, v in data.items()}
        offset = self._fh.tell()
        Metadata(name=name, metadata=text).write(self._rb)
        self._metadata_indexes.append(
            MetadataIndex(offset=offset, length=self._rb.count, name=name)
        )
        self._emit()

    # ------------------------------------------------------------------ records
    def _emit(self) -> None:
        self._fh.write(self._rb.end())

    def _channel(self, topic: str, msgtype: str, rank: int) -> int:
        """The channel id of ``topic``; a new one (and its schema) is recorded into the open
        chunk just before the message of batch rank ``rank``."""
        ch = self._channels.get(topic)
        if ch is not None:
            return int(ch.id)
        from mcap.records import Channel, Schema

        from uwval.io.ros import typestore

        schema = self._schemas.get(msgtype)
        if schema is None:
            text, _ = typestore(2).generate_msgdef(msgtype, ros_version=2)
            schema = Schema(
                id=len(self._schemas) + 1, data=text.encode(), encoding="ros2msg", name=msgtype
            )
            self._schemas[msgtype] = schema
            self._pending_defs.append((3 * rank, schema))
        ch = Channel(
            id=len(self._channels) + 1,
            topic=topic,
            message_encoding="cdr",
            schema_id=schema.id,
            metadata={"offered_qos_profiles": ""},
        )
        self._channels[topic] = ch
        self._next_seq[ch.id] = 0
        self._counts[ch.id] = 0
        self._pending_defs.append((3 * rank + 1, ch))
        return int(ch.id)

    def write_blocks(self, blocks: list[RawBlock]) -> None:
        """Append the messages of ``blocks`` to the open chunk, in rank order."""
        if self._closed:
            raise LogWriteError(f"{self.path}: the log is closed")
        base = self._pending_n
        for b in blocks:
            n = b.rows.shape[0]
            if n == 0:
                continue
            log = np.asarray(b.log_times, dtype=np.int64)
            if int(log.min()) < 0:
                raise LogWriteError(
                    f"{self.path}: cannot write to {b.topic}: negative log time {int(log.min())} ns"
                )
            ranks = np.asarray(b.ranks, dtype=np.int64) + base
            cid = self._channel(b.topic, b.msgtype, int(ranks.min()))
            width = b.rows.shape[1]
            rec = np.empty((n, _MSG_HEAD + width), dtype=np.uint8)
            rec[:, 0] = 0x05  # Message
            rec[:, 1:9] = np.full(n, 22 + width, dtype="<u8").view(np.uint8).reshape(n, 8)
            rec[:, 9:11] = np.frombuffer(struct.pack("<H", cid), dtype=np.uint8)
            seq = self._next_seq[cid] + np.arange(n, dtype=np.int64)
            rec[:, 11:15] = (seq & 0xFFFFFFFF).astype("<u4").view(np.uint8).reshape(n, 4)
            lt = log.astype("<u8").view(np.uint8).reshape(n, 8)
            rec[:, 15:23] = lt
            rec[:, 23:31] = lt
            rec[:, 31:] = b.rows
            self._next_seq[cid] += n
            self._counts[cid] += n
            self._segments.append((cid, rec, log, ranks))
            self._pending_bytes += rec.size
            lo, hi = int(log.min()), int(log.max())
            self._start = lo if self._n == 0 else min(self._start, lo)
            self._end = max(self._end, hi)
            self._n += n
        self._pending_n = base + sum(b.rows.shape[0] for b in blocks)
        if self._pending_bytes > self.chunk_size:
            self._finish_chunk()

    def write_raw(
        self, topic: str, msgtype: str, data: bytes, log_time: int, publish_time: int | None = None
    ) -> None:
        """Write one already CDR-encoded message (``publish_time`` is the log time)."""
        rows = np.frombuffer(bytes(data), dtype=np.uint8).reshape(1, -1)
        self.write_blocks(
            [RawBlock(topic, msgtype, rows, np.array([int(log_time)]), np.zeros(1, np.int64))]
        )

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
        rows = encode_pose_block(np.array([int(t_ns)]), position, quat, frame_id)
        log = int(t_ns) if log_time is None else int(log_time)
        self.write_blocks(
            [RawBlock(topic, POSE_STAMPED, rows, np.array([log]), np.zeros(1, np.int64))]
        )

    def write_header(self, topic: str, stamp_ns: int, log_time: int, frame_id: str = "") -> None:
        """Write one std_msgs/Header stamped ``stamp_ns`` and logged at ``log_time``."""
        rows = encode_header_block(np.array([int(stamp_ns)]), frame_id)
        self.write_blocks(
            [RawBlock(topic, HEADER, rows, np.array([int(log_time)]), np.zeros(1, np.int64))]
        )

    def _finish_chunk(self) -> None:
        """Write the open chunk (the messages in rank order, a new channel's schema and
        channel records just before its first message) and its message indexes."""
        import zlib

        import zstandard
        from mcap.data_stream import RecordBuilder
        from mcap.records import Chunk, ChunkIndex

        if not self._segments:
            return
        # slots 3r, 3r + 1: a schema, a channel before message r; 3r + 2: message r
        size = np.zeros(3 * self._pending_n, dtype=np.int64)
        defs = []
        for slot, record in self._pending_defs:
            rb = RecordBuilder()
            record.write(rb)
            defs.append((slot, rb.end()))
            size[slot] = len(defs[-1][1])
        self._pending_defs = []
        for _, rec, _, ranks in self._segments:
            size[3 * ranks + 2] = rec.shape[1]
        offset = np.zeros(size.size, dtype=np.int64)
        np.cumsum(size[:-1], out=offset[1:])
        buf = np.empty(int(size.sum()), dtype=np.uint8)
        for slot, raw in defs:
            buf[offset[slot] : offset[slot] + len(raw)] = np.frombuffer(raw, dtype=np.uint8)
        per_channel: dict[int, list[tuple[I64, I64]]] = {}
        lo = hi = None
        for cid, rec, log, ranks in self._segments:
            off = offset[3 * ranks + 2]
            buf[off[:, None] + np.arange(rec.shape[1])] = rec
            per_channel.setdefault(cid, []).append((log, off))
            a, z = int(log.min()), int(log.max())
            lo = a if lo is None else min(lo, a)
            hi = z if hi is None else max(hi, z)
        data = buf.tobytes()
        compressed = zstandard.compress(data)
        chunk = Chunk(
            compression="zstd",
            data=compressed,
            message_start_time=int(lo or 0),
            message_end_time=int(hi or 0),
            uncompressed_crc=zlib.crc32(data),
            uncompressed_size=len(data),
        )
        start = self._fh.tell()
        chunk.write(self._rb)
        length = self._rb.count
        self._emit()
        index_start = self._fh.tell()
        offsets: dict[int, int] = {}
        parts = []
        pos = 0
        first = {cid: min(int(o.min()) for _, o in parts_) for cid, parts_ in per_channel.items()}
        # MessageIndex records, built with numpy, in the order the channels first appear
        for cid in sorted(per_channel, key=first.__getitem__):
            log = np.concatenate([p[0] for p in per_channel[cid]])
            off = np.concatenate([p[1] for p in per_channel[cid]])
            order = np.argsort(off, kind="stable")
            pairs = np.empty((log.size, 2), dtype="<u8")
            pairs[:, 0] = log[order]
            pairs[:, 1] = off[order]
            body = struct.pack("<HI", cid, pairs.size * 8) + pairs.tobytes()
            parts.append(struct.pack("<BQ", 0x07, len(body)) + body)
            offsets[cid] = index_start + pos
            pos += len(parts[-1])
        self._fh.write(b"".join(parts))
        self._chunk_indexes.append(
            ChunkIndex(
                message_start_time=chunk.message_start_time,
                message_end_time=chunk.message_end_time,
                chunk_start_offset=start,
                chunk_length=length,
                message_index_offsets=offsets,
                message_index_length=pos,
                compression="zstd",
                compressed_size=len(compressed),
                uncompressed_size=len(data),
            )
        )
        self._segments = []
        self._pending_bytes = 0
        self._pending_n = 0

    def flush(self) -> None:
        """Finish the open chunk and push the file's bytes to the OS."""
        if self._closed:
            return
        self._finish_chunk()
        self._fh.flush()

    def close(self) -> None:
        """Finish the log: last chunk, DataEnd, summary (schemas, channels, statistics, chunk
        and metadata indexes, summary offsets), footer with the summary CRC (idempotent)."""
        if self._closed:
            return
        import zlib

        from mcap.data_stream import RecordBuilder
        from mcap.opcode import Opcode
        from mcap.records import DataEnd, Footer, Statistics, SummaryOffset

        try:
            self._finish_chunk()
            DataEnd(data_section_crc=0).write(self._rb)
            self._emit()
            summary_start = self._fh.tell()
            sb = RecordBuilder()
            groups: list[tuple[int, int, int]] = []

            def group(opcode: int, records: list[Any]) -> None:
                g0 = sb.count
                for r in records:
                    r.write(sb)
                groups.append((opcode, summary_start + g0, sb.count - g0))

            group(Opcode.SCHEMA, list(self._schemas.values()))
            group(Opcode.CHANNEL, list(self._channels.values()))
            stats = Statistics(
                attachment_count=0,
                channel_count=len(self._channels),
                channel_message_counts=dict(self._counts),
                chunk_count=len(self._chunk_indexes),
                message_count=self._n,
                message_end_time=self._end,
                message_start_time=self._start,
                metadata_count=len(self._metadata_indexes),
                schema_count=len(self._schemas),
            )
            group(Opcode.STATISTICS, [stats])
            group(Opcode.CHUNK_INDEX, self._chunk_indexes)
            group(Opcode.ATTACHMENT_INDEX, [])
            group(Opcode.METADATA_INDEX, self._metadata_indexes)
            offset_start = summary_start + sb.count
            for opcode, g_start, g_len in groups:
                SummaryOffset(group_opcode=opcode, group_start=g_start, group_length=g_len).write(
                    sb
                )
            summary = sb.end()
            crc = zlib.crc32(summary)
            crc = zlib.crc32(
                struct.pack("<BQQQ", Opcode.FOOTER, 20, summary_start, offset_start), crc
            )
            self._fh.write(summary)
            Footer(
                summary_start=summary_start, summary_offset_start=offset_start, summary_crc=crc
            ).write(self._rb)
            self._emit()
            self._fh.write(_MCAP_MAGIC)
        except OSError as exc:
            raise LogWriteError(f"{self.path}: cannot finish log: {exc}") from exc
        finally:
            self._closed = True
            self._fh.close()

    def __enter__(self) -> McapBlockWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


_MCAP_MAGIC = b"\x89MCAP0\r\n"


# --------------------------------------------------------------------------- ROS 1 bag writer
_BAG1_CHUNK_THRESHOLD = 1 << 20  # rosbags' Writer.chunk_threshold
_BAG1_MSG_HEAD = 4 + 38 + 4  # header length, op/conn/time fields, data length


class Bag1BlockWriter:
    """A ROS 1 bag (v2.0, uncompressed chunks) writer that takes whole blocks of serialized
    messages (:class:`RawBlock`).

    The file is what :class:`uwval.io.writers.Rosbag1PoseWriter` writes through rosbags'
    Writer (same records, same chunk boundaries at 1 MiB, same index and chunk-info records,
    the ``/uwval/metadata`` message first), but a block's message-data records are built with
    numpy at once, and only the open chunk's index is kept in memory (rosbags keeps every
    message's index entry until close: ~170 MiB for an hour of ``uwval simulate``). Records
    other than messages are written with rosbags' own ``Header`` and ``write_connection``.
    Readable by rosbags' AnyReader and uwval's readers (tests/test_recorder_blocks.py).
    """

    encoding = "ros1"

    def __init__(self, path: str | Path, *, metadata: dict[str, str] | None = None) -> None:
        from rosbags.rosbag1.writer import Header

        self.path = Path(path)
        try:  # an earlier file is replaced, as uwval's open_writer does
            self._fh = open(self.path, "wb")  # noqa: SIM115 - closed in close()
        except OSError as exc:
            raise LogWriteError(f"{self.path}: cannot create ROS 1 bag: {exc}") from exc
        self._conns: dict[str, Any] = {}  # topic -> rosbags Connection
        self._chunk: list[bytes] = []  # records of the open chunk
        self._chunk_size = 0
        self._index: dict[int, list[tuple[I64, I64]]] = {}  # open chunk: conn -> (times, offs)
        self._start = 2**63 - 1
        self._end = 0
        self._infos: list[tuple[int, int, int, dict[int, int]]] = []  # pos, start, end, counts
        self._closed = False
        self._fh.write(b"#ROSBAG V2.0\n")
        self._bag_header(Header, 0, 0, 0)
        if metadata:
            import json

            from uwval.io.ros import typestore

            ts = typestore(1)
            msg = ts.types["std_msgs/msg/String"](data=json.dumps(metadata))
            data = bytes(ts.serialize_ros1(msg, "std_msgs/msg/String"))
            self.write_raw("/uwval/metadata", "std_msgs/msg/String", data, 0)

    def _bag_header(self, header_cls: Any, index_pos: int, conns: int, chunks: int) -> None:
        from rosbags.rosbag1.reader import RecordType

        h = header_cls()
        h.set_uint64("index_pos", index_pos)
        h.set_uint32("conn_count", conns)
        h.set_uint32("chunk_count", chunks)
        size = h.write(self._fh, RecordType.BAGHEADER)
        pad = 4096 - 4 - size
        self._fh.write(struct.pack("<I", pad) + b" " * pad)

    def _connection(self, topic: str, msgtype: str) -> tuple[int, bytes]:
        """(id, connection record bytes or b"" when known) of ``topic``'s connection."""
        import io

        from rosbags.interfaces import (
            Connection,
            ConnectionExtRosbag1,
            MessageDefinition,
            MessageDefinitionFormat,
        )
        from rosbags.rosbag1.writer import Writer

        from uwval.io.ros import typestore

        conn = self._conns.get(topic)
        if conn is not None:
            return int(conn.id), b""
        msgdef, md5 = typestore(1).generate_msgdef(msgtype)
        conn = Connection(
            len(self._conns),
            topic,
            msgtype,
            MessageDefinition(MessageDefinitionFormat.MSG, msgdef),
            md5,
            -1,
            ConnectionExtRosbag1(None, None),
            self,
        )
        self._conns[topic] = conn
        bio = io.BytesIO()
        Writer.write_connection(conn, bio)
        return int(conn.id), bio.getvalue()

    def write_blocks(self, blocks: list[RawBlock]) -> None:
        """Append the messages of ``blocks`` in rank order, finishing a chunk after the
        message that takes it past 1 MiB (as rosbags' Writer does)."""
        if self._closed:
            raise LogWriteError(f"{self.path}: the log is closed")
        n_total = sum(b.rows.shape[0] for b in blocks)
        if n_total == 0:
            return
        # slots 2r: a new connection's record before message r; 2r + 1: message r
        size = np.zeros(2 * n_total, dtype=np.int64)
        conn_recs: list[tuple[int, bytes]] = []
        segs = []
        for b in blocks:
            n = b.rows.shape[0]
            if n == 0:
                continue
            log = np.asarray(b.log_times, dtype=np.int64)
            if int(log.min()) < 0 or int(log.max()) // _NS > _UINT32_MAX:
                raise LogWriteError(
                    f"{self.path}: cannot write to {b.topic}: log time outside ROS 1 time"
                )
            ranks = np.asarray(b.ranks, dtype=np.int64)
            cid, rec_bytes = self._connection(b.topic, b.msgtype)
            if rec_bytes:
                conn_recs.append((2 * int(ranks.min()), rec_bytes))
                size[2 * int(ranks.min())] = len(rec_bytes)
            width = b.rows.shape[1]
            rec = np.empty((n, _BAG1_MSG_HEAD + width), dtype=np.uint8)
            head = struct.pack("<II", 38, 4) + b"op=\x02" + struct.pack("<I", 9) + b"conn="
            head += struct.pack("<I", cid) + struct.pack("<I", 13) + b"time="
            rec[:, : len(head)] = np.frombuffer(head, dtype=np.uint8)
            sec, nsec = np.divmod(log, _NS)
            rec[:, 34:38] = sec.astype("<u4").view(np.uint8).reshape(n, 4)
            rec[:, 38:42] = nsec.astype("<u4").view(np.uint8).reshape(n, 4)
            rec[:, 42:46] = np.frombuffer(struct.pack("<I", width), dtype=np.uint8)
            rec[:, 46:] = b.rows
            size[2 * ranks + 1] = rec.shape[1]
            segs.append((cid, rec, log, ranks))
        offset = np.zeros(size.size, dtype=np.int64)
        np.cumsum(size[:-1], out=offset[1:])
        buf = np.empty(int(size.sum()), dtype=np.uint8)
        for slot, raw in conn_recs:
            buf[offset[slot] : offset[slot] + len(raw)] = np.frombuffer(raw, dtype=np.uint8)
        times = np.empty(n_total, dtype=np.int64)
        cids = np.empty(n_total, dtype=np.int64)
        for cid, rec, log, ranks in segs:
            buf[offset[2 * ranks + 1][:, None] + np.arange(rec.shape[1])] = rec
            times[ranks] = log
            cids[ranks] = cid
        msg_start = offset[1::2]  # where message r starts in buf
        msg_end = msg_start + size[1::2]
        done = 0  # messages of this batch already in a written or open chunk
        pos = 0  # bytes of buf consumed
        while done < n_total:
            # the chunk finishes after the first message whose end takes it past the threshold
            over = self._chunk_size + (msg_end[done:] - pos) > _BAG1_CHUNK_THRESHOLD
            k = int(np.argmax(over)) if bool(over.any()) else n_total - done - 1
            last = done + k
            end = int(msg_end[last])
            base = self._chunk_size - pos
            self._chunk.append(buf[pos:end].tobytes())
            sl = slice(done, last + 1)
            for cid in dict.fromkeys(cids[sl].tolist()):
                sel = cids[sl] == cid
                self._index.setdefault(cid, []).append((times[sl][sel], msg_start[sl][sel] + base))
            self._start = min(self._start, int(times[sl].min()))
            self._end = max(self._end, int(times[sl].max()))
            self._chunk_size += end - pos
            pos = end
            done = last + 1
            if bool(over.any()):
                self._write_chunk()

    def write_raw(
        self, topic: str, msgtype: str, data: bytes, log_time: int, publish_time: int | None = None
    ) -> None:
        """Write one already ROS 1-serialized message."""
        rows = np.frombuffer(bytes(data), dtype=np.uint8).reshape(1, -1)
        self.write_blocks(
            [RawBlock(topic, msgtype, rows, np.array([int(log_time)]), np.zeros(1, np.int64))]
        )

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
        rows = encode_pose_block(np.array([int(t_ns)]), position, quat, frame_id, "ros1")
        log = int(t_ns) if log_time is None else int(log_time)
        self.write_blocks(
            [RawBlock(topic, POSE_STAMPED, rows, np.array([log]), np.zeros(1, np.int64))]
        )

    def write_header(self, topic: str, stamp_ns: int, log_time: int, frame_id: str = "") -> None:
        """Write one std_msgs/Header stamped ``stamp_ns`` and logged at ``log_time``."""
        rows = encode_header_block(np.array([int(stamp_ns)]), frame_id, "ros1")
        self.write_blocks(
            [RawBlock(topic, HEADER, rows, np.array([int(log_time)]), np.zeros(1, np.int64))]
        )

    def _write_chunk(self) -> None:
        """Write the open chunk record and its index-data records (one per connection)."""
        from rosbags.rosbag1.reader import RecordType
        from rosbags.rosbag1.writer import Header

        if self._chunk_size == 0:
            return
        pos = self._fh.tell()
        h = Header()
        h.set_string("compression", "none")
        h.set_uint32("size", self._chunk_size)
        h.write(self._fh, RecordType.CHUNK)
        self._fh.write(struct.pack("<I", self._chunk_size))
        for part in self._chunk:
            self._fh.write(part)
        counts = {}
        for cid, parts in self._index.items():
            t = np.concatenate([p[0] for p in parts])
            off = np.concatenate([p[1] for p in parts])
            entries = np.empty((t.size, 3), dtype="<u4")
            entries[:, 0], entries[:, 1] = np.divmod(t, _NS)
            entries[:, 2] = off
            ih = Header()
            ih.set_uint32("ver", 1)
            ih.set_uint32("conn", cid)
            ih.set_uint32("count", t.size)
            ih.write(self._fh, RecordType.IDXDATA)
            self._fh.write(struct.pack("<I", t.size * 12) + entries.tobytes())
            counts[cid] = int(t.size)
        self._infos.append((pos, self._start, self._end, counts))
        self._chunk, self._chunk_size, self._index = [], 0, {}
        self._start, self._end = 2**63 - 1, 0

    def flush(self) -> None:
        """Nothing to push (as uwval's ROS 1 writer: a bag is indexed by ``close()``)."""

    def close(self) -> None:
        """Write the open chunk, the connection and chunk-info records, and the bag header
        (idempotent)."""
        if self._closed:
            return
        from rosbags.rosbag1.reader import RecordType
        from rosbags.rosbag1.writer import Header, Writer

        try:
            self._write_chunk()
            index_pos = self._fh.tell()
            for conn in self._conns.values():
                Writer.write_connection(conn, self._fh)
            for pos, start, end, counts in self._infos:
                h = Header()
                h.set_uint32("ver", 1)
                h.set_uint64("chunk_pos", pos)
                h.set_time("start_time", 0 if start == 2**63 - 1 else start)
                h.set_time("end_time", end)
                h.set_uint32("count", len(counts))
                h.write(self._fh, RecordType.CHUNK_INFO)
                body = b"".join(struct.pack("<II", c, n) for c, n in counts.items())
                self._fh.write(struct.pack("<I", len(counts) * 8) + body)
            self._fh.seek(13)
            self._bag_header(Header, index_pos, len(self._conns), len(self._infos))
        except OSError as exc:
            raise LogWriteError(f"{self.path}: cannot finish log: {exc}") from exc
        finally:
            self._closed = True
            self._fh.close()

    def __enter__(self) -> Bag1BlockWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


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


class BridgeRecorder:
    """Write Gazebo-side and Unity-side poses of one run through ``writer``.

    With a writer that takes serialized messages (``write_raw``: uwval's log writers) the
    recorder keeps the messages since the last flush as columns and, at each flush, encodes
    every topic's block at once with numpy (:func:`encode_pose_block`,
    :func:`encode_header_block`, in the writer's ``encoding``) and writes the blocks in the
    order the messages came (``write_blocks`` of :class:`McapBlockWriter` in one call, else
    ``write_raw`` message by message): the same messages, bytes and order as writing each at
    once, without a Python serialization per message. Any other :class:`PoseWriter` gets
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
        self.blocks = callable(getattr(writer, "write_raw", None))
        self.encoding = str(getattr(writer, "encoding", "cdr"))
        self._pending: dict[str, _Pending] = {}
        self._rank = 0
        self._topics: dict[tuple[str, str], str] = {}
        # per (prefix, name, frame_id): the topic's pending buffer (and applied-stamp buffer)
        self._gz: dict[tuple[str, str], _Pending] = {}
        self._un: dict[str, tuple[_Pending, _Pending]] = {}

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
        buf.stamps.append(t)
        buf.logs.append(log)
        buf.ranks.append(self._rank)
        buf.pos.append(position)
        buf.quat.append(quat)
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
        pose.stamps.append(t)
        pose.logs.append(t)
        pose.ranks.append(self._rank)
        pose.pos.append(position)
        pose.quat.append(quat)
        self._rank += 1
        self._tick()  # may flush between the pose and its stamp, as message by message
        applied.stamps.append(int(applied_stamp_ns))
        applied.logs.append(t)
        applied.ranks.append(self._rank)
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
                rows = encode_header_block(stamps, buf.frame_id, self.encoding)
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
                rows = encode_pose_block(stamps, pos, quat, buf.frame_id, self.encoding)
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
        write_raw_blocks(self.writer, blocks)

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
) -> McapBlockWriter:
    """A :class:`McapBlockWriter` for a recorder (64 KiB chunks, so that a crash loses
    little; its ``flush()`` finishes the open chunk)."""
    return McapBlockWriter(path, metadata=metadata, chunk_size=chunk_size)


def open_log_writer(
    path: str | Path, format: str = "mcap", metadata: dict[str, str] | None = None
) -> Any:
    """The log writer of a recorded run: :class:`McapBlockWriter` for ``mcap`` and
    :class:`Bag1BlockWriter` for ``rosbag1`` (blocks of messages at once; an earlier file
    there is replaced, as uwval's writers do), uwval's writers (:func:`uwval.io.open_writer`)
    for rosbag2 (rosbags' writer, message by message)."""
    if format == "mcap":
        return McapBlockWriter(path, metadata=metadata)
    if format in ("rosbag1", "bag"):
        return Bag1BlockWriter(path, metadata=metadata)
    from uwval.io import open_writer

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
