"""Issue 15 (perf): the fast read paths give exactly what the reference libraries give.

The container readers check a chunk's index for all channels at once and copy fixed-width
pose payloads straight into one preallocated buffer per topic (sized by the container's own
counts); rosbag2 sqlite3 fetches every selected topic in one query. These tests hold them to
the libraries (mcap, rosbags) on interleaved logs written by those libraries and on the
benchmark's real shapes, and check the edge cases of the preallocated buffer (a count that
lies, a width that changes) and the index check's diagnosis.
"""

from __future__ import annotations

import struct
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

import io_loggen as gen

from uwval.io import read_streams
from uwval.io.containers import scan_log
from uwval.io.mcap_chunk import check_index as check_chunks
from uwval.io.raw import TopicBuilder

FORMATS = [("mcap", ".mcap"), ("bag", ".bag"), ("rosbag2-sqlite3", ""), ("rosbag2-mcap", "")]
SELECTED = (gen.GAZEBO, gen.UNITY, gen.APPLIED)


def _reference(path: Path, topics: tuple[str, ...]) -> dict[str, list[tuple[int, bytes]]]:
    """(log time ns, payload bytes) per topic, in the order the reference library reads."""
    out: dict[str, list[tuple[int, bytes]]] = {t: [] for t in topics}
    if path.suffix == ".mcap":
        from mcap.reader import make_reader

        with open(path, "rb") as fh:
            for _s, ch, m in make_reader(fh, validate_crcs=True).iter_messages(
                topics=list(topics), log_time_order=False
            ):
                out[ch.topic].append((m.log_time, bytes(m.data)))
        return out
    from rosbags.highlevel import AnyReader

    with AnyReader([path]) as r:
        conns = [c for c in r.connections if c.topic in topics]
        for c, t, data in r.messages(connections=conns):
            out[c.topic].append((t, bytes(data)))
    return out


@pytest.mark.parametrize(("fmt", "suffix"), FORMATS)
def test_selected_payloads_equal_the_reference_library(
    tmp_path: Path, fmt: str, suffix: str
) -> None:
    """Every selected message's bytes and log time, as mcap / rosbags read them (32 kB
    chunks: many chunks, every topic interleaved in each, an image topic beside them)."""
    p = gen.write_log(tmp_path / f"log{suffix}", fmt, seconds=3.0, image_bytes=3000)
    log = scan_log(p, list(SELECTED))
    ref = _reference(p, SELECTED)
    for topic in SELECTED:
        raw = log.raw[topic]
        assert len(raw) == len(ref[topic]) > 100, topic
        assert raw.buf.shape[0] == int(raw.length.sum())  # only its own bytes survive
        got = sorted((int(raw.log_time[i]), raw.payload(i)) for i in range(len(raw)))
        assert got == sorted(ref[topic]), topic
        assert not raw.dropped and not log.warnings


def test_shapes_read_identically_across_formats(tmp_path: Path) -> None:
    """The benchmark's real shapes (uwval's topics, /tf with 5 children, interleaved) give
    the same numbers from MCAP, ROS 1, rosbag2 sqlite3 and rosbag2 MCAP."""
    from benchmarks.shapes import GAZEBO_VEHICLE, UNITY_VEHICLE, Shape, generate

    topics = [GAZEBO_VEHICLE, UNITY_VEHICLE]
    got = {}
    for fmt in ("mcap", "rosbag1", "rosbag2-sqlite3", "rosbag2-mcap"):
        f = generate(Shape(f"s-{fmt}", fmt, 4.0), tmp_path)
        got[fmt] = read_streams(f.paths[0], topics)
    first = got["mcap"]
    assert len(first[GAZEBO_VEHICLE]) == 400 and len(first[UNITY_VEHICLE]) > 200
    assert first[UNITY_VEHICLE].applied_stamp is not None
    for fmt, streams in got.items():
        for t in topics:
            a, b = first[t], streams[t]
            np.testing.assert_array_equal(a.t, b.t, err_msg=f"{fmt} {t}")
            np.testing.assert_array_equal(a.position, b.position, err_msg=f"{fmt} {t}")
            np.testing.assert_array_equal(a.orientation, b.orientation, err_msg=f"{fmt} {t}")
            np.testing.assert_array_equal(a.applied_stamp, b.applied_stamp)
            assert not b.warnings and not b.dropped


def test_the_benchmark_settles_shapes_without_changing_a_byte(tmp_path: Path) -> None:
    """The page-cache states the shape benchmark measures from (read from disk: evicted and
    read again; as written: rewritten in 4 kB writes) keep every file, of a single-file log
    and of a rosbag2 folder, byte for byte, and what uwval reads from it."""
    from benchmarks.bench_shapes import AS_WRITTEN, READ_FROM_DISK, _files, settle
    from benchmarks.shapes import GAZEBO_VEHICLE, Shape, generate

    for fmt in ("mcap", "rosbag2-mcap"):
        f = generate(Shape(f"s-{fmt}", fmt, 2.0), tmp_path)
        files = _files(f.paths)
        assert files and all(p.is_file() for p in files)
        before = {p: p.read_bytes() for p in files}
        want = read_streams(f.paths[0], [GAZEBO_VEHICLE])[GAZEBO_VEHICLE]
        for state in (AS_WRITTEN, READ_FROM_DISK):
            settle(f, state)
            assert _files(f.paths) == files
            assert {p: p.read_bytes() for p in files} == before, state
            got = read_streams(f.paths[0], [GAZEBO_VEHICLE])[GAZEBO_VEHICLE]
            np.testing.assert_array_equal(got.position, want.position)
        assert not list(tmp_path.rglob("*.rewrite"))


def test_shape_poses_equal_mcap_ros2(tmp_path: Path) -> None:
    """The MCAP shape's decoded poses equal mcap_ros2's per-message decode, bit for bit."""
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    from benchmarks.shapes import GAZEBO_VEHICLE, Shape, generate

    f = generate(Shape("s-mcap", "mcap", 3.0), tmp_path)
    s = read_streams(f.paths[0], [GAZEBO_VEHICLE], frame="enu")[GAZEBO_VEHICLE]
    rows = []
    with open(f.paths[0], "rb") as fh:
        reader = make_reader(fh, decoder_factories=[DecoderFactory()])
        for _s, _c, _m, msg in reader.iter_decoded_messages(topics=[GAZEBO_VEHICLE]):
            p, q, st = msg.pose.position, msg.pose.orientation, msg.header.stamp
            rows.append((st.sec * 10**9 + st.nanosec, p.x, p.y, p.z, q.x, q.y, q.z, q.w))
    rows.sort(key=lambda r: r[0])
    np.testing.assert_array_equal(s.t, np.array([r[0] for r in rows], dtype=np.int64))
    ref = np.array([r[1:] for r in rows], dtype=np.float64)
    np.testing.assert_array_equal(s.position, ref[:, :3])
    # PoseStream normalises quaternions; the shapes' are unit already, to the last bit or so
    np.testing.assert_allclose(s.orientation, ref[:, 3:], rtol=0, atol=1e-15)


def _segments(rng: np.random.Generator, widths: list[int]) -> list[tuple[np.ndarray, ...]]:
    """Chunk-like buffers with messages of ``width`` bytes at irregular starts."""
    out = []
    t = 0
    for w in widths:
        n = int(rng.integers(1, 40))
        gaps = rng.integers(0, 30, size=n)
        starts = np.cumsum(gaps + w) - w
        buf = rng.integers(0, 256, size=int(starts[-1]) + w + 5, dtype=np.uint8)
        times = np.arange(t, t + n, dtype=np.int64)
        t += n
        out.append((buf, starts.astype(np.int64), times, np.int64(w)))
    return out


@pytest.mark.parametrize("widths", [[12] * 6, [12, 12, 20, 12, 20]])
def test_take_rows_equals_plain_adds(widths: list[int]) -> None:
    """A builder filled with row gathers builds the same topic as one filled with plain
    adds, also when the width changes from segment to segment."""
    rng = np.random.default_rng(7)
    segs = _segments(rng, widths)
    total = sum(len(s[1]) for s in segs)
    fast = TopicBuilder("/t", "geometry_msgs/msg/PoseStamped", "cdr")
    slow = TopicBuilder("/t", "geometry_msgs/msg/PoseStamped", "cdr")
    for buf, starts, times, w in segs:
        fast.take_rows(buf, starts, int(w), times)
        slow.add(buf, starts, np.full(len(starts), w, np.int64), times)
    assert len(fast) == total
    a, b = fast.build(), slow.build()
    np.testing.assert_array_equal(a.log_time, b.log_time)
    np.testing.assert_array_equal(a.length, b.length)
    assert [a.payload(i) for i in range(total)] == [b.payload(i) for i in range(total)]
    assert a.buf.shape[0] == int(a.length.sum())  # nothing but the rows kept


def _chunk(records: list[tuple[int, int, bytes]]) -> tuple[np.ndarray, dict[int, np.ndarray]]:
    """Decompressed chunk bytes of MCAP Message records (channel, log time, payload) and its
    MessageIndex entries per channel."""
    out = bytearray()
    ents: dict[int, list[tuple[int, int]]] = {}
    for cid, lt, data in records:
        ents.setdefault(cid, []).append((lt, len(out)))
        out += struct.pack("<BQHIQQ", 5, 22 + len(data), cid, 0, lt, lt) + data
    return np.frombuffer(bytes(out), dtype=np.uint8), {
        c: np.array(e, dtype=np.uint64) for c, e in ents.items()
    }


def check_index(buf: np.ndarray, ents: dict[int, np.ndarray]) -> tuple[str, Any]:
    """The index check of one chunk (``buf`` holds its records), channel by channel."""
    groups, lo = [], 0
    for cid, e in ents.items():
        groups.append((cid, lo, lo := lo + len(e)))
    rows = np.concatenate(list(ents.values())).astype(np.uint64)
    chunk = np.zeros(len(rows), np.intp)
    return check_chunks(buf, rows, chunk, groups, np.array([0, len(buf)], np.int64))


def test_check_index_names_the_channel_and_the_fault() -> None:
    recs = [(c, 1000 + k, bytes([k]) * (8 + c)) for k in range(20) for c in (1, 2, 3)]
    buf, ents = _chunk(recs)
    reason, checked = check_index(buf, ents)
    assert reason == ""
    assert len(checked.rec) == len(checked.length) == 60
    starts = np.concatenate([e[:, 1] for e in ents.values()]).astype(np.int64)
    np.testing.assert_array_equal(checked.rec, starts)  # row order: channel by channel
    np.testing.assert_array_equal(
        checked.length, [22 + 8 + c for c in (1, 2, 3) for _ in range(20)]
    )

    bad = {c: e.copy() for c, e in ents.items()}
    bad[2][5, 0] += 1
    assert check_index(buf, bad)[0] == "channel 2: an entry's log time differs from its message's"

    bad = {c: e.copy() for c, e in ents.items()}
    bad[3][0, 1] += 1  # points into the middle of a record
    assert check_index(buf, bad)[0].startswith("channel 3: ")

    bad = {c: e.copy() for c, e in ents.items()}
    bad[1][2, 1] = bad[2][2, 1]  # channel 1's entry at channel 2's message
    assert check_index(buf, bad)[0] == (
        "channel 1: an entry points at a message of another channel"
    )

    bad = {c: e.copy() for c, e in ents.items()}
    bad[2][1, 1] = np.uint64(2**63 + 5)  # would wrap as int64
    assert check_index(buf, bad)[0] == "channel 2: an entry points outside the chunk"

    bad = {c: e[:-1] for c, e in ents.items()}  # the last message of each left out
    assert "missing from the index" in check_index(buf, bad)[0]


@pytest.mark.parametrize(("fmt", "suffix"), FORMATS)
def test_uniform_rows_decode_equals_rosbags(tmp_path: Path, fmt: str, suffix: str) -> None:
    """Pose topics read from the containers are rows of one width; decoding them through
    the (n, width) view gives rosbags' per-message values, also when some rows are bad."""
    from uwval.io.decode import decode_poses
    from uwval.io.fastdecode import _Bytes

    p = gen.write_log(tmp_path / f"log{suffix}", fmt, seconds=2.0, image_bytes=0)
    log = scan_log(p, [gen.GAZEBO, gen.APPLIED])
    for topic in (gen.GAZEBO, gen.APPLIED):
        raw = log.raw[topic]
        assert _Bytes(raw.buf, raw.offset, raw.length).rows2d is not None, topic
        fast = decode_poses(raw) if topic == gen.GAZEBO else None
        if fast is not None:
            slow = decode_poses(raw, fast=False)
            assert fast.handled.all()
            np.testing.assert_array_equal(fast.pose, slow.pose)
            np.testing.assert_array_equal(fast.stamp, slow.stamp)
            assert [fast.names[c] for c in fast.frame_code] == [
                slow.names[c] for c in slow.frame_code
            ]
    if fmt == "bag":
        return
    # a big-endian CDR header on one message, a frame name without its NUL on another:
    # those rows leave the fast path (rosbags decides), the others stay bit-identical
    raw = log.raw[gen.GAZEBO]
    w = int(raw.length[0])
    buf = raw.buf.copy()
    buf[3 * w + 1] = 0  # encapsulation kind 0x0000: big-endian CDR
    frame_len = int(buf[12 * w + 12 : 12 * w + 16].view("<u4")[0])
    buf[12 * w + 16 + frame_len - 1] = ord("x")  # the NUL of "world" overwritten
    from uwval.io.fastdecode import fast_decode

    dec = fast_decode(raw.msgtype, raw.encoding, buf, raw.offset, raw.length)
    assert not dec.handled[3] and not dec.handled[12]
    assert dec.handled.sum() == len(raw) - 2
    ref = decode_poses(raw, fast=False)
    keep = dec.handled
    np.testing.assert_array_equal(dec.pose[keep], ref.pose[keep])
    np.testing.assert_array_equal(dec.stamp[keep], ref.stamp[keep])
