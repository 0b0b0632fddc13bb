"""Damaged logs (issue 14): never a wrong number without a warning, never a traceback.

Each test damages a log written by the real libraries the way the issue's probe did and
checks what uwval says: the same numbers as the intact file with a warning, or fewer samples
counted by cause in ``PoseStream.dropped``, or a one-line :class:`LogReadError` naming the
file and the byte offset.
"""

from __future__ import annotations

import os
import shutil
import struct
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import io_loggen as gen
from cli_runner import run_uwval

from uwval.errors import LogReadError
from uwval.io import read_stream, read_streams
from uwval.io.raw import LogWarning, TruncatedLogWarning


def _read(path: Path, topics: list[str] | None = None) -> dict[str, object]:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", LogWarning)
        return dict(read_streams(path, topics or list(gen.POSE_TOPICS)))


def _mcap_records(data: bytes) -> list[tuple[int, int, int]]:
    """(offset, opcode, length) of the top-level records of an MCAP file."""
    out = []
    pos = 8
    while pos + 9 <= len(data):
        op, ln = struct.unpack_from("<BQ", data, pos)
        out.append((pos, op, ln))
        if op == 2:  # footer
            break
        pos += 9 + ln
    return out


@pytest.fixture
def mcap_log(tmp_path: Path) -> Path:
    return gen.write_log(tmp_path / "intact.mcap", "mcap", seconds=3.0, image_bytes=1500)


def test_zeroed_message_index_is_noticed_and_read_by_walking(
    mcap_log: Path, tmp_path: Path
) -> None:
    intact = _read(mcap_log)
    data = bytearray(mcap_log.read_bytes())
    # zero 64 bytes of the entries of a MessageIndex (the probe): the offsets now
    # point at the chunk's first record, a message of another topic
    idx = [(p, ln) for p, op, ln in _mcap_records(bytes(data)) if op == 7 and ln > 80]
    pos, _ln = idx[len(idx) // 2]
    data[pos + 9 + 6 : pos + 9 + 6 + 64] = bytes(64)
    bad = tmp_path / "zeroed_index.mcap"
    bad.write_bytes(bytes(data))
    with pytest.warns(LogWarning, match=r"MessageIndex disagrees with its records"):
        got = read_streams(bad, list(gen.POSE_TOPICS))
    for t in gen.POSE_TOPICS:
        np.testing.assert_array_equal(got[t].t, intact[t].t)
        np.testing.assert_array_equal(got[t].position, intact[t].position)
        np.testing.assert_array_equal(got[t].orientation, intact[t].orientation)
    assert any("walking its records" in w for t in gen.POSE_TOPICS for w in got[t].warnings)


def test_bit_flip_in_a_zstd_chunk_fails_the_crc_and_is_counted(
    mcap_log: Path, tmp_path: Path
) -> None:
    from mcap.reader import make_reader

    intact = _read(mcap_log)
    data = bytearray(mcap_log.read_bytes())
    chunks = [(p, ln) for p, op, ln in _mcap_records(bytes(data)) if op == 6]
    pos, ln = chunks[1]
    data[pos + 9 + ln - 40] ^= 0x10  # inside the compressed records
    bad = tmp_path / "flip.mcap"
    bad.write_bytes(bytes(data))
    # the mcap library refuses the file (its CRC error or zstd's error: any of its types)
    with pytest.raises(Exception), open(bad, "rb") as fh:  # noqa: B017
        list(make_reader(fh, validate_crcs=True).iter_messages())
    got = _read(bad)
    for t in gen.POSE_TOPICS:
        s = got[t]
        lost = len(intact[t]) - len(s)
        assert lost > 0
        assert sum(s.dropped.values()) == lost, s.dropped
        assert set(s.dropped) <= {"crc_mismatch", "damaged_chunk"}
        assert any(f"chunk at byte {pos}" in w for w in s.warnings)
        # what is left is exactly the intact file's samples
        assert np.isin(s.t, intact[t].t).all()


def test_killed_writer_mcap_says_not_closed_cleanly(tmp_path: Path) -> None:
    from uwval.io import McapPoseWriter

    p = tmp_path / "killed.mcap"
    w = McapPoseWriter(p, chunk_size=4096)
    t = np.arange(300, dtype=np.int64) * 10**7 + 10**9
    w.write_poses(gen.GAZEBO, t, np.ones((300, 3)), np.tile([0, 0, 0, 1.0], (300, 1)), "world")
    w.flush()
    snapshot = p.read_bytes()
    w.close()
    p.write_bytes(snapshot)  # no summary, no footer
    with pytest.warns(TruncatedLogWarning, match=r"killed\.mcap: log was not closed cleanly.*300"):
        s = read_stream(p, gen.GAZEBO)
    assert len(s) == 300
    assert s.warnings


def test_cut_inside_the_only_chunk_recovers_its_prefix(tmp_path: Path) -> None:
    from mcap.reader import make_reader

    p = gen.write_log(tmp_path / "one.mcap", "mcap", seconds=3.0, chunk_size=1 << 24)
    intact = _read(p)
    data = p.read_bytes()
    assert sum(op == 6 for _p, op, _l in _mcap_records(data)) == 1
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) * 2 // 3])
    with pytest.warns(TruncatedLogWarning):
        got = read_streams(cut, list(gen.POSE_TOPICS))
    for t in gen.POSE_TOPICS:
        n = len(got[t])
        assert 0 < n < len(intact[t])
        np.testing.assert_array_equal(got[t].t, intact[t].t[:n])
        np.testing.assert_array_equal(got[t].position, intact[t].position[:n])
    # the mcap library's reader sees the same file as cut (it has no recover in Python)
    with pytest.raises(Exception), open(cut, "rb") as fh:  # noqa: B017
        list(make_reader(fh).iter_messages())


def test_undecodable_message_is_dropped_and_counted(tmp_path: Path) -> None:
    from uwval.io import McapPoseWriter

    p = tmp_path / "bad_msg.mcap"
    with McapPoseWriter(p) as w:
        for k in range(50):
            w.write_pose(
                gen.GAZEBO, 10**9 + k * 10**7, np.zeros(3) + k, np.array([0, 0, 0, 1.0]), "world"
            )
        # a message whose frame_id length runs past its end: no decoder can read it
        w.write_raw(
            gen.GAZEBO,
            "geometry_msgs/msg/PoseStamped",
            b"\x00\x01\x00\x00" + bytes(8) + b"\xff\x00\x00\x00",
            2 * 10**9,
        )
    s = read_stream(p, gen.GAZEBO)
    assert len(s) == 50
    assert s.dropped == {"decode_error": 1}


def test_duplicate_stamps_are_counted(tmp_path: Path) -> None:
    from uwval.io import McapPoseWriter

    p = tmp_path / "dup.mcap"
    with McapPoseWriter(p) as w:
        for k in range(20):
            w.write_pose(
                gen.GAZEBO, 10**9 + (k // 2) * 10**7, np.zeros(3), np.array([0, 0, 0, 1.0]), "world"
            )
    s = read_stream(p, gen.GAZEBO)
    assert len(s) == 10
    assert s.dropped == {"duplicate_stamp": 10}


# ---------------------------------------------------------------- ROS 1
def _bag_chunks(data: bytes) -> list[tuple[int, dict[str, bytes], int, int]]:
    """(offset, header fields, data start, data length) of the chunk records of a bag."""
    from uwval.io.bag1_raw import _record

    out = []
    pos = 13
    _hdr, _ds, _dl, pos = _record(data, pos, len(data))
    while pos < len(data):
        h, ds, dl, nxt = _record(data, pos, len(data))
        if h["op"][0] == 0x05:
            out.append((pos, h, ds, dl))
        if h["op"][0] in (0x06, 0x07) and pos > 13 and not out:
            break
        pos = nxt
    return out


@pytest.mark.parametrize("compression", ["lz4", "bz2"])
def test_corrupted_ros1_chunk_is_dropped_with_a_warning(tmp_path: Path, compression: str) -> None:
    p = gen.write_log(tmp_path / "c.bag", "bag", compression=compression, seconds=3.0)
    intact = _read(p)
    data = bytearray(p.read_bytes())
    pos, _h, ds, dl = _bag_chunks(bytes(data))[1]
    # lz4: the frame's block header (LZ4F_decompress fails); bz2: the middle (bz2's CRC)
    at = ds + 7 if compression == "lz4" else ds + dl // 2
    data[at : at + 16] = b"\xa5" * 16
    bad = tmp_path / "bad.bag"
    bad.write_bytes(bytes(data))
    got = _read(bad)
    for t in gen.POSE_TOPICS:
        lost = len(intact[t]) - len(got[t])
        assert lost > 0 and got[t].dropped == {"damaged_chunk": lost}
        assert any(f"chunk at byte {pos} is damaged" in w for w in got[t].warnings)


def test_ros1_compression_field_swapped_bz2_to_lz4(tmp_path: Path) -> None:
    p = gen.write_log(tmp_path / "c.bag", "bag", compression="bz2", seconds=3.0)
    intact = _read(p)
    data = p.read_bytes()
    first = data.index(b"compression=bz2")
    bad = tmp_path / "swapped.bag"
    bad.write_bytes(data[:first] + b"compression=lz4" + data[first + 15 :])
    got = _read(bad)
    for t in gen.POSE_TOPICS:
        assert len(got[t]) < len(intact[t])
        assert "damaged_chunk" in got[t].dropped
        assert any("lz4 data cannot be decompressed" in w for w in got[t].warnings)


def test_zeroed_region_of_a_ros1_bag_is_counted(tmp_path: Path) -> None:
    p = gen.write_log(tmp_path / "z.bag", "bag", compression="none", seconds=3.0)
    intact = _read(p)
    data = bytearray(p.read_bytes())
    _pos, _h, ds, _dl = _bag_chunks(bytes(data))[1]
    data[ds + 1000 : ds + 1400] = bytes(400)  # inside the chunk's records
    bad = tmp_path / "zeroed.bag"
    bad.write_bytes(bytes(data))
    got = _read(bad)
    for t in gen.POSE_TOPICS:
        lost = len(intact[t]) - len(got[t])
        assert sum(got[t].dropped.values()) == lost
        if lost:
            assert got[t].warnings
        assert np.isin(got[t].t, intact[t].t).all()


def test_zeroed_ros1_index_data_never_asserts(tmp_path: Path) -> None:
    p = gen.write_log(tmp_path / "i.bag", "bag", compression="none", seconds=3.0)
    intact = _read(p)
    data = bytearray(p.read_bytes())
    pos, _h, ds, dl = _bag_chunks(bytes(data))[0]
    data[ds + dl : ds + dl + 200] = bytes(200)  # the IndexData records after the chunk
    bad = tmp_path / "zeroed_index.bag"
    bad.write_bytes(bytes(data))
    got = _read(bad)
    for t in gen.POSE_TOPICS:
        np.testing.assert_array_equal(got[t].t, intact[t].t)
        np.testing.assert_array_equal(got[t].position, intact[t].position)
        assert any(f"chunk at byte {pos}" in w for w in got[t].warnings)


# ---------------------------------------------------------------- rosbag2
def test_rosbag2_empty_relative_file_paths_entry_is_one_line(tmp_path: Path) -> None:
    p = gen.write_log(tmp_path / "r2", "rosbag2-sqlite3", seconds=1.0)
    meta = p / "metadata.yaml"
    text = meta.read_text()
    lines = text.splitlines()
    k = next(i for i, ln in enumerate(lines) if "relative_file_paths" in ln)
    indent = lines[k + 1][: len(lines[k + 1]) - len(lines[k + 1].lstrip())]
    lines.insert(k + 1, indent + "-")
    meta.write_text("\n".join(lines) + "\n")
    with pytest.raises(LogReadError, match=r"metadata\.yaml: relative_file_paths entry \d") as e:
        read_stream(p, gen.GAZEBO)
    assert "\n" not in str(e.value)


@pytest.mark.parametrize("storage", ["rosbag2-sqlite3", "rosbag2-mcap"])
def test_rosbag2_without_metadata_says_not_closed_cleanly(tmp_path: Path, storage: str) -> None:
    p = gen.write_log(tmp_path / "r2", storage, seconds=1.0)
    intact = _read(p)
    (p / "metadata.yaml").unlink()
    with pytest.warns(TruncatedLogWarning, match=r"not closed cleanly \(no metadata\.yaml"):
        s = read_stream(p, gen.GAZEBO)
    assert len(s) == len(intact[gen.GAZEBO])


def test_rosbag2_metadata_counts_more_than_the_storage_holds(tmp_path: Path) -> None:
    import sqlite3

    p = gen.write_log(tmp_path / "r2", "rosbag2-sqlite3", seconds=1.0)
    intact = _read(p)
    db = next(p.glob("*.db3"))
    con = sqlite3.connect(db)
    con.execute(
        "DELETE FROM messages WHERE id IN (SELECT messages.id FROM messages JOIN topics ON "
        "topics.id = messages.topic_id WHERE topics.name = ? LIMIT 7)",
        (gen.GAZEBO,),
    )
    con.commit()
    con.close()
    s = _read(p)[gen.GAZEBO]
    assert len(s) == len(intact[gen.GAZEBO]) - 7
    assert s.dropped == {"missing": 7}


# ---------------------------------------------------------------- special files
@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no FIFOs here")
def test_inspect_refuses_a_fifo_instead_of_hanging(tmp_path: Path) -> None:
    fifo = tmp_path / "log.mcap"
    os.mkfifo(fifo)
    r = run_uwval("inspect", fifo, timeout=60)
    assert r.returncode != 0
    assert "not a regular file" in r.stderr + r.stdout
    assert "Traceback" not in r.stderr
    txt = tmp_path / "poses.txt"
    os.mkfifo(txt)
    with pytest.raises(LogReadError, match="not a regular file"):
        read_stream(txt, "")


def test_compare_json_carries_reader_warnings_and_drops(mcap_log: Path, tmp_path: Path) -> None:
    import json

    data = bytearray(mcap_log.read_bytes())
    chunks = [(p, ln) for p, op, ln in _mcap_records(bytes(data)) if op == 6]
    pos, ln = chunks[1]
    data[pos + 9 + ln - 40] ^= 0x10
    bad = tmp_path / "flip.mcap"
    bad.write_bytes(bytes(data))
    r = run_uwval("compare", bad, "--json", timeout=120)
    assert r.returncode == 0, r.stderr
    doc = json.loads(r.stdout)
    assert any(
        ("not used" in w and "crc_mismatch" in w) or "damaged_chunk" in w for w in doc["warnings"]
    )
    assert any(f"chunk at byte {pos}" in w for w in doc["warnings"])


def test_copy_is_untouched(tmp_path: Path) -> None:
    """The readers never write next to a log (a damaged log stays as it was)."""
    p = gen.write_log(tmp_path / "r2", "rosbag2-sqlite3", seconds=1.0)
    before = sorted(x.name for x in p.iterdir())
    shutil.copytree(p, tmp_path / "copy")
    _read(p)
    assert sorted(x.name for x in p.iterdir()) == before
