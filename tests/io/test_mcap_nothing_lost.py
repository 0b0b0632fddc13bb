"""MCAP logs that once lost messages with no word (issue 29): each case reads the same
messages as the ``mcap`` library's own reader, or warns naming the byte offset and counts what
it lost.

The logs are written by ``mcap``'s Writer and damaged byte by byte the way a disk or a
half-finished copy would; the expected messages come from mcap's reader of the intact file.
"""

from __future__ import annotations

import itertools
import struct
import zlib
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from uwval.io.encode import encode_pose_stamped
from uwval.io.mcap_raw import scan_mcap
from uwval.io.raw import RawLog

WANTED = ("/gazebo/model_rov_pose", "/unity/model_rov_pose")
OTHER = "/other/pose"
TOPICS = (*WANTED, OTHER)


class _PrivateRecords:
    """A file whose writes get a private record (opcode 0x80-0xFF, which the MCAP spec
    reserves for extensions) after the Header and after every Chunk record: between a
    chunk and its MessageIndex records."""

    def __init__(self, fh: Any) -> None:
        self.fh = fh

    def write(self, data: Any) -> int:
        data = bytes(data)
        self.fh.write(data)
        if data[:1] in (b"\x01", b"\x06"):
            body = b"private extension bytes"
            self.fh.write(struct.pack("<BQ", 0x81, len(body)) + body)
        return len(data)

    def tell(self) -> int:
        return int(self.fh.tell())

    def flush(self) -> None:
        self.fh.flush()


def _write(
    path: Path,
    *,
    compression: str = "zstd",
    statistics: bool = True,
    crcs: bool = True,
    private: bool = False,
) -> Path:
    """Three PoseStamped topics interleaved in small chunks (2 s at 100 Hz each)."""
    from mcap.writer import CompressionType, Writer

    comp = {"zstd": CompressionType.ZSTD, "none": CompressionType.NONE}[compression]
    n = 200
    rng = np.random.default_rng(7)
    with open(path, "wb") as fh:
        out: Any = _PrivateRecords(fh) if private else fh
        w = Writer(
            out,
            chunk_size=2048,
            compression=comp,
            use_statistics=statistics,
            enable_crcs=crcs,
        )
        w.start(profile="ros2", library="uwval-tests")
        sid = w.register_schema(
            name="geometry_msgs/msg/PoseStamped", encoding="ros2msg", data=b"# a pose\n"
        )
        chans = [w.register_channel(t, "cdr", sid) for t in TOPICS]
        t = 10**18 + np.arange(n, dtype=np.int64) * 10_000_000
        rows = []
        for _ in TOPICS:
            q = rng.normal(size=(n, 4))
            q /= np.linalg.norm(q, axis=1, keepdims=True)
            rows.append(encode_pose_stamped(t, rng.normal(size=(n, 3)), q, "world", "cdr"))
        for i in range(n):
            for k, cid in enumerate(chans):
                stamp = int(t[i]) + k
                w.add_message(cid, log_time=stamp, publish_time=stamp, data=rows[k][i].tobytes())
        w.finish()
    return path


def _records(data: bytes) -> list[tuple[int, int, int]]:
    """(offset, opcode, length) of the top-level records of an MCAP file."""
    out, pos = [], 8
    while pos + 9 <= len(data):
        op, ln = struct.unpack_from("<BQ", data, pos)
        out.append((pos, op, ln))
        if op == 2:
            break
        pos += 9 + ln
    return out


def _mcap_messages(path: Path) -> dict[str, list[tuple[int, bytes]]]:
    """(log time, payload) per topic, as the mcap library's reader reads them."""
    from mcap.reader import make_reader

    out: dict[str, list[tuple[int, bytes]]] = {}
    with open(path, "rb") as fh:
        for _s, ch, msg in make_reader(fh).iter_messages():
            out.setdefault(ch.topic, []).append((msg.log_time, bytes(msg.data)))
    return out


def _ours(log: RawLog, topic: str) -> list[tuple[int, bytes]]:
    raw = log.raw[topic]
    return [(int(raw.log_time[i]), raw.payload(i)) for i in range(len(raw))]


def _chunk_messages(data: bytes, pos: int) -> dict[int, int]:
    """Messages per channel id in the chunk record at ``pos``, from its MessageIndex records."""
    recs = _records(data)
    k = next(i for i, r in enumerate(recs) if r[0] == pos)
    out = {}
    for p, op, _ln in recs[k + 1 :]:
        if op != 7:
            break
        (cid,) = struct.unpack_from("<H", data, p + 9)
        (nbytes,) = struct.unpack_from("<I", data, p + 11)
        out[cid] = nbytes // 16
    return out


def test_private_records_are_skipped_without_a_warning(tmp_path: Path) -> None:
    log = _write(tmp_path / "private.mcap", private=True)
    data = log.read_bytes()
    ops = [op for _p, op, _l in _records(data)]
    # a private record right after every chunk, before its MessageIndex records
    assert any(a == 6 and b == 0x81 for a, b in itertools.pairwise(ops))
    expected = _mcap_messages(log)
    got = scan_mcap(log, None)
    assert got.all_warnings() == []
    for topic in TOPICS:
        assert _ours(got, topic) == expected[topic]
        assert got.raw[topic].dropped == {}


@pytest.mark.parametrize("opcode", [0x09, 0x05, 0x00, 0x81])
def test_damaged_chunk_opcode_without_statistics_is_warned_and_counted(
    tmp_path: Path, opcode: int
) -> None:
    log = _write(tmp_path / "intact.mcap", statistics=False)
    data = bytearray(log.read_bytes())
    chunks = [p for p, op, _l in _records(bytes(data)) if op == 6]
    pos = chunks[len(chunks) // 2]
    lost = _chunk_messages(bytes(data), pos)
    assert sum(lost.values()) > 0
    data[pos] = opcode
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(bytes(data))
    intact = scan_mcap(log, WANTED)
    got = scan_mcap(bad, WANTED)
    assert any(f"chunk at byte {pos}" in w for w in got.warnings), got.warnings
    for cid, topic in enumerate(TOPICS, start=1):
        if topic not in WANTED:
            continue
        raw = got.raw[topic]
        assert len(intact.raw[topic]) - len(raw) == lost[cid]
        assert sum(raw.dropped.values()) == lost[cid], raw.dropped
        # what is left is exactly the intact file's messages
        assert set(_ours(got, topic)) <= set(_ours(intact, topic))


def test_message_index_with_a_wrong_channel_id_does_not_skip_the_chunk(tmp_path: Path) -> None:
    log = _write(tmp_path / "intact.mcap", statistics=False)
    data = bytearray(log.read_bytes())
    recs = _records(bytes(data))
    # the index of the gazebo channel (id 1) now claims the unwanted channel (id 3)
    k = next(i for i, r in enumerate(recs) if r[1] == 6 and i > len(recs) // 3)
    idx = [(p, ln) for p, op, ln in recs[k + 1 :][:3] if op == 7]
    for p, _ln in idx:
        (cid,) = struct.unpack_from("<H", data, p + 9)
        if cid == 1:
            struct.pack_into("<H", data, p + 9, 3)
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(bytes(data))
    expected = _mcap_messages(log)
    got = scan_mcap(bad, WANTED[:1])  # every index of the chunk now names unwanted channels
    assert _ours(got, WANTED[0]) == expected[WANTED[0]]
    assert any(f"chunk at byte {recs[k][0]}" in w for w in got.warnings), got.warnings


def _table_records(data: bytes, pos: int, op: int) -> list[int]:
    """Offsets (in the file) of the ``op`` records inside the uncompressed chunk at ``pos``
    (its records start at ``_records_at(data, pos)``)."""
    rec_at = _records_at(data, pos)
    (usize,) = struct.unpack_from("<Q", data, pos + 9 + 16)
    out, q = [], rec_at
    while q < rec_at + usize:
        o, ln = struct.unpack_from("<BQ", data, q)
        if o == op:
            out.append(q)
        q += 9 + ln
    return out


def _records_at(data: bytes | bytearray, pos: int) -> int:
    """Where the records of the uncompressed chunk at ``pos`` start in the file."""
    (comp_len,) = struct.unpack_from("<I", data, pos + 9 + 28)
    return pos + 9 + 32 + comp_len + 8


def _fix_crc(data: bytearray, pos: int) -> None:
    """Recompute the CRC of the uncompressed chunk at ``pos`` (a file that contradicts
    itself, yet passes every checksum)."""
    c = pos + 9
    (usize,) = struct.unpack_from("<Q", data, c + 16)
    (comp_len,) = struct.unpack_from("<I", data, c + 28)
    rec_at = c + 32 + comp_len + 8
    struct.pack_into("<I", data, c + 24, zlib.crc32(bytes(data[rec_at : rec_at + usize])))


def test_channel_redefined_with_another_topic_is_warned(tmp_path: Path) -> None:
    log = _write(tmp_path / "intact.mcap", compression="none")
    data = bytearray(log.read_bytes())
    pos = next(p for p, op, _l in _records(bytes(data)) if op == 6)
    channels = _table_records(bytes(data), pos, 4)
    at = channels[0]
    (cid,) = struct.unpack_from("<H", data, at + 9)
    # the topic's last character changes: the same channel id now names another topic
    (tlen,) = struct.unpack_from("<I", data, at + 9 + 4)
    data[at + 9 + 8 + tlen - 1] ^= 0x01
    _fix_crc(data, pos)
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(bytes(data))
    got = scan_mcap(bad, None)
    where = f"at byte {at - _records_at(data, pos)} of the records of the chunk at byte {pos}"
    assert any(f"Channel {cid} {where}" in w for w in got.warnings), got.warnings


def test_damaged_repeated_schema_in_a_crc_less_chunk_is_warned(tmp_path: Path) -> None:
    log = _write(tmp_path / "intact.mcap", compression="none", crcs=False)
    data = bytearray(log.read_bytes())
    pos = next(p for p, op, _l in _records(bytes(data)) if op == 6)
    at = _table_records(bytes(data), pos, 3)[0]
    (sid,) = struct.unpack_from("<H", data, at + 9)
    data[at + 9 + 40] ^= 0x20  # inside the schema's name or text
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(bytes(data))
    got = scan_mcap(bad, None)
    where = f"at byte {at - _records_at(data, pos)} of the records of the chunk at byte {pos}"
    assert any(f"Schema {sid} {where}" in w for w in got.warnings), got.warnings


def test_intact_log_reads_as_mcaps_reader_does(tmp_path: Path) -> None:
    for comp in ("zstd", "none"):
        log = _write(tmp_path / f"intact-{comp}.mcap", compression=comp)
        expected = _mcap_messages(log)
        got = scan_mcap(log, WANTED)
        assert got.all_warnings() == []
        assert set(got.raw) == set(WANTED)
        for topic in WANTED:
            assert _ours(got, topic) == expected[topic]
        assert {i.name: i.count for i in got.topics} == {t: 200 for t in TOPICS}


def test_an_index_out_of_file_order_is_still_right(tmp_path: Path) -> None:
    """A MessageIndex listing its channel's records out of file order is right (the check
    sorts them): read with no warning, the same messages as mcap's reader (in its order)."""
    log = _write(tmp_path / "intact.mcap")
    data = bytearray(log.read_bytes())
    recs = _records(bytes(data))
    k = next(i for i, r in enumerate(recs) if r[1] == 6 and i > len(recs) // 2)
    at = recs[k + 1][0] + 9 + 6  # the entries of the chunk's first MessageIndex
    data[at : at + 16], data[at + 16 : at + 32] = data[at + 16 : at + 32], data[at : at + 16]
    bad = tmp_path / "swapped.mcap"
    bad.write_bytes(bytes(data))
    got = scan_mcap(bad, WANTED)
    assert got.all_warnings() == []
    expected = _mcap_messages(log)
    for topic in WANTED:
        assert sorted(_ours(got, topic)) == expected[topic]


def test_many_channels_metadata_and_a_large_chunk_read_as_mcaps_reader(tmp_path: Path) -> None:
    """300 channels defined in one chunk, Metadata and Attachment records between chunks, and
    a chunk larger than a run of chunks: every message as mcap's reader reads it."""
    from mcap.writer import CompressionType, Writer

    from uwval.io import mcap_raw

    path = tmp_path / "many.mcap"
    with open(path, "wb") as fh:
        w = Writer(fh, chunk_size=64 * 1024, compression=CompressionType.ZSTD)
        w.start(profile="", library="uwval-tests")
        sid = w.register_schema(name="raw", encoding="", data=b"")
        chans = [w.register_channel(f"/t{k}", "raw", sid) for k in range(300)]
        for i in range(6000):
            w.add_message(chans[i % 300], log_time=i, publish_time=i, data=bytes([i % 251]) * 12)
            if i % 997 == 0:
                w.add_metadata("note", {"i": str(i)})
                w.add_attachment(i, i, "a.bin", "application/octet-stream", b"x" * 100)
        big = bytes(range(256)) * (mcap_raw.BATCH_BYTES // 256 + 1000)  # one chunk > a run
        w.add_message(chans[0], log_time=6000, publish_time=6000, data=big)
        w.finish()
    got = scan_mcap(path, None)
    assert got.all_warnings() == []
    expected = _mcap_messages(path)
    assert set(got.raw) == set(expected) and len(got.raw) == 300
    for topic, msgs in expected.items():
        assert _ours(got, topic) == msgs


def test_a_footer_without_summary_is_not_damage(tmp_path: Path) -> None:
    """A footer whose summary offset is 0 (a writer that leaves the summary out) is a
    finished log: read whole, without a warning."""
    log = _write(tmp_path / "intact.mcap", compression="none")
    data = log.read_bytes()
    end = next(p for p, op, _l in _records(data) if op == 15)  # DataEnd
    footer = struct.pack("<BQQQI", 2, 20, 0, 0, 0)
    bare = tmp_path / "bare.mcap"
    bare.write_bytes(data[:end] + data[end : end + 9 + 4] + footer + data[-8:])
    expected = _mcap_messages(log)
    got = scan_mcap(bare, WANTED)
    assert got.all_warnings() == []
    for topic in WANTED:
        assert _ours(got, topic) == expected[topic]


def test_a_log_cut_in_its_last_chunk_keeps_the_recovered_messages(tmp_path: Path) -> None:
    """Every message counted is read: the messages recovered from the prefix of a chunk cut
    off by the end of the file were once counted while their channels were not defined yet
    (the chunks before it, which define them, were read after it), and dropped without a
    word."""
    from mcap.reader import make_reader

    log = _loggen().write_log(
        tmp_path / "log.mcap", "mcap", seconds=6.0, image_bytes=500, chunk_size=4096,
        compression="none",
    )  # fmt: skip
    with open(log, "rb") as fh:
        summary = make_reader(fh).get_summary()
        fh.seek(0)
        whole: dict[str, list[tuple[int, bytes]]] = {t: [] for t in WANTED}
        for _s, ch, m in make_reader(fh).iter_messages(topics=list(whole), log_time_order=False):
            whole[ch.topic].append((m.log_time, bytes(m.data)))
    assert summary is not None
    last = summary.chunk_indexes[-1]
    start, first_index = last.chunk_start_offset, min(last.message_index_offsets.values())
    log.write_bytes(log.read_bytes()[: start + (first_index - start) * 9 // 10])
    got = scan_mcap(log, None)
    assert got.cut_detail and "recovered 0 " not in got.cut_detail, got.cut_detail
    assert sum(len(r) for r in got.raw.values()) == sum(i.count for i in got.topics)
    late = 0
    for t, msgs in whole.items():
        raw = got.raw[t]
        kept = [(int(raw.log_time[i]), raw.payload(i)) for i in range(len(raw))]
        assert kept == msgs[: len(kept)], t  # a prefix of the log, in file order
        assert (np.diff(raw.log_time) >= 0).all()
        late += sum(1 for lt, _p in kept if lt >= last.message_start_time)
    assert late > 0  # some of them come from the cut chunk


def _loggen() -> Any:
    """tests/io_loggen.py (the interleaved logs of the io tests)."""
    import sys

    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    import io_loggen

    return io_loggen
