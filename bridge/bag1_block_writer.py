"""A ROS 1 bag writer that takes blocks of serialized messages (issue 15): rosbags' bag, with a
block's message-data records built with numpy and only the open chunk's index in memory."""

from __future__ import annotations

import struct
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from uwval.bridge.blocks import (
    _NS,
    _UINT32_MAX,
    OneMessageWrites,
    RawBlock,
)
from uwval.errors import LogWriteError

I64 = NDArray[np.int64]

_BAG1_CHUNK_THRESHOLD = 1 << 20  # rosbags' Writer.chunk_threshold
_BAG1_MSG_HEAD = 4 + 38 + 4  # header length, op/conn/time fields, data length


class Bag1BlockWriter(OneMessageWrites):
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
