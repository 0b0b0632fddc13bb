"""Chunks read in runs (decompressed into one buffer, one index check and one row gather for
several chunks) give exactly what reading them one by one gives: the same messages, drops and
warnings, also when a chunk in the middle of a run is damaged or a channel first appears in a
later chunk. The reference is always the chunk-by-chunk read (``BATCH_BYTES = 0``)."""

from __future__ import annotations

import struct
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import io_loggen as gen

from uwval.io import mcap_raw
from uwval.io.raw import RawLog

TOPICS = ["/gazebo/model_rov_pose", "/unity/model_rov_pose", "/tf", "/camera/image_raw/compressed"]


def _scan(path: Path, batch: int, monkeypatch: pytest.MonkeyPatch) -> RawLog:
    """Read with runs of ``batch`` bytes of records; 0: chunk by chunk."""
    monkeypatch.setattr(mcap_raw, "BATCH_BYTES", batch)
    return mcap_raw.scan_mcap(path, TOPICS)


def _same(a: RawLog, b: RawLog) -> None:
    assert a.warnings == b.warnings
    assert a.topics == b.topics
    assert a.raw.keys() == b.raw.keys()
    for name, ta in a.raw.items():
        tb = b.raw[name]
        assert ta.dropped == tb.dropped, name
        assert np.array_equal(ta.log_time, tb.log_time), name
        assert len(ta) == len(tb)
        for i in range(len(ta)):
            assert ta.payload(i) == tb.payload(i), (name, i)


def _chunks(path: Path) -> list[tuple[int, dict[int, int]]]:
    """(chunk record start, {channel: MessageIndex record start}) of every chunk."""
    from mcap.reader import make_reader

    with open(path, "rb") as fh:
        summary = make_reader(fh).get_summary()
    assert summary is not None
    return [(c.chunk_start_offset, dict(c.message_index_offsets)) for c in summary.chunk_indexes]


@pytest.fixture(params=["zstd", "lz4", "none"])
def log(tmp_path: Path, request: pytest.FixtureRequest) -> Path:
    # small chunks: a batch (2 MB of records) holds dozens of them
    return gen.write_log(
        tmp_path / "log.mcap",
        "mcap",
        seconds=6.0,
        image_bytes=500,
        chunk_size=4096,
        compression=request.param,
    )


def test_batches_read_what_single_chunks_read(log: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    n_chunks = len(_chunks(log))
    assert n_chunks > 20
    calls: list[int] = []
    check = mcap_raw.check_index

    def counting(buf: np.ndarray, rows: Any, chunk: Any, groups: Any, at: np.ndarray) -> Any:
        calls.append(len(at) - 1)  # chunks checked in the call
        return check(buf, rows, chunk, groups, at)

    monkeypatch.setattr(mcap_raw, "check_index", counting)
    batched = _scan(log, mcap_raw.BATCH_BYTES, monkeypatch)
    assert max(calls) > 20  # the chunks were checked together in one numpy call
    assert not batched.warnings
    _same(batched, _scan(log, 0, monkeypatch))
    assert len(batched.raw["/gazebo/model_rov_pose"]) == 600
    # many small runs: buffers are reused, nothing read earlier may change
    _same(_scan(log, 20_000, monkeypatch), batched)


def test_a_damaged_chunk_mid_batch_is_reported_alone(
    log: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    data = bytearray(log.read_bytes())
    chunks = _chunks(log)
    start, _ = chunks[len(chunks) // 2]
    data[start + 9 + 60] ^= 0xFF  # inside the (compressed) records
    log.write_bytes(bytes(data))
    batched = _scan(log, mcap_raw.BATCH_BYTES, monkeypatch)
    assert len(batched.warnings) == 1
    assert f"MCAP chunk at byte {start}" in batched.warnings[0]
    assert sum(sum(t.dropped.values()) for t in batched.raw.values()) > 0
    _same(batched, _scan(log, 0, monkeypatch))


def test_a_wrong_index_entry_mid_batch_is_reported_for_its_chunk(
    log: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    data = bytearray(log.read_bytes())
    chunks = _chunks(log)
    start, index_at = chunks[len(chunks) // 2 + 1]
    at = min(index_at.values()) + 9 + 2 + 4  # the first entry's log time
    (t,) = struct.unpack_from("<Q", data, at)
    struct.pack_into("<Q", data, at, t + 1)
    log.write_bytes(bytes(data))
    batched = _scan(log, mcap_raw.BATCH_BYTES, monkeypatch)
    assert len(batched.warnings) == 1
    assert f"MCAP chunk at byte {start}: its MessageIndex disagrees" in batched.warnings[0]
    _same(batched, _scan(log, 0, monkeypatch))


def test_a_channel_first_seen_in_a_later_chunk(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from mcap.writer import Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    typ = "geometry_msgs/msg/PoseStamped"
    text, _ = ts.generate_msgdef(typ, ros_version=2)
    path = tmp_path / "late.mcap"
    with open(path, "wb") as fh:
        w = Writer(fh, chunk_size=2048)
        w.start(profile="ros2", library="uwval-tests")
        sid = w.register_schema(name=typ, encoding="ros2msg", data=text.encode())
        chans: dict[str, int] = {}
        for k in range(400):
            names = TOPICS[:1] if k < 200 else TOPICS[:2]  # the Unity topic starts later
            for name in names:
                if name not in chans:
                    chans[name] = w.register_channel(
                        topic=name, message_encoding="cdr", schema_id=sid
                    )
                msg = ts.types[typ](
                    header=ts.types["std_msgs/msg/Header"](
                        stamp=ts.types["builtin_interfaces/msg/Time"](sec=k, nanosec=0),
                        frame_id="world",
                    ),
                    pose=ts.types["geometry_msgs/msg/Pose"](
                        position=ts.types["geometry_msgs/msg/Point"](x=float(k), y=0.0, z=0.0),
                        orientation=ts.types["geometry_msgs/msg/Quaternion"](
                            x=0.0, y=0.0, z=0.0, w=1.0
                        ),
                    ),
                )
                t = k * 10_000_000
                w.add_message(
                    chans[name], log_time=t, publish_time=t, data=bytes(ts.serialize_cdr(msg, typ))
                )
        w.finish()
    batched = _scan(path, mcap_raw.BATCH_BYTES, monkeypatch)
    assert len(batched.raw[TOPICS[1]]) == 200
    _same(batched, _scan(path, 0, monkeypatch))


@pytest.mark.parametrize("delta", [-1, 1, 1 << 40])
def test_a_chunk_whose_size_is_wrong_mid_batch(
    log: Path, monkeypatch: pytest.MonkeyPatch, delta: int
) -> None:
    data = bytearray(log.read_bytes())
    chunks = _chunks(log)
    start, _ = chunks[len(chunks) // 3]
    at = start + 9 + 16  # the chunk's uncompressed size
    (usize,) = struct.unpack_from("<Q", data, at)
    struct.pack_into("<Q", data, at, usize + delta)
    log.write_bytes(bytes(data))
    batched = _scan(log, mcap_raw.BATCH_BYTES, monkeypatch)
    assert len(batched.warnings) == 1
    assert f"MCAP chunk at byte {start}" in batched.warnings[0]
    _same(batched, _scan(log, 0, monkeypatch))


def test_a_log_cut_in_its_last_chunk_keeps_file_order(
    log: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The decompressible prefix of a chunk cut off by the end of the file is read after the
    chunks queued before it (it once went first: its messages led every topic)."""
    chunks = _chunks(log)
    start, offsets = chunks[-1]
    data = log.read_bytes()
    cut = start + (min(offsets.values()) - start) * 9 // 10
    log.write_bytes(data[:cut])  # the last chunk cut, no summary
    batched = _scan(log, mcap_raw.BATCH_BYTES, monkeypatch)
    assert batched.unclean
    if b"zstd" not in data[:4096] and b"lz4" not in data[:4096]:
        # a stored chunk's prefix gives messages (one compressed block gives none)
        assert "recovered 0 message" not in batched.cut_detail, batched.cut_detail
    for name, topic in batched.raw.items():
        assert (np.diff(topic.log_time) >= 0).all(), name  # written in time order
    _same(batched, _scan(log, 0, monkeypatch))


def test_message_indexes_of_a_lost_chunk_are_not_the_next_chunks(
    log: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A Chunk record damaged into another opcode is passed over; its MessageIndex records
    are then nobody's (they once joined the next chunk's, ahead of its own)."""
    chunks = _chunks(log)
    k = next(
        i
        for i in range(1, len(chunks) - 1)
        if sorted(chunks[i][1], key=chunks[i][1].get)
        != sorted(chunks[i + 1][1], key=chunks[i + 1][1].get)
    )
    data = bytearray(log.read_bytes())
    data[chunks[k][0]] = 0x0C  # a Metadata record now (of the chunk's length)
    log.write_bytes(bytes(data))
    batched = _scan(log, mcap_raw.BATCH_BYTES, monkeypatch)
    # the lost chunk is named and its messages counted from its own index; the next chunk
    # read with its own index (no disagreement warned)
    assert len(batched.warnings) == 1, batched.warnings
    assert f"MCAP chunk at byte {chunks[k][0]} has opcode 0x0c" in batched.warnings[0]
    assert "disagrees" not in batched.warnings[0]
    assert sum(sum(t.dropped.values()) for t in batched.raw.values()) > 0
    _same(batched, _scan(log, 0, monkeypatch))
