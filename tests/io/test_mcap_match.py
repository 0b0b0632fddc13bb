"""The C walk that checks a decompressed MCAP chunk against its MessageIndex
(``uwval.io._mcapwalk.match_chunk``, run on the inflate thread) agrees with the numpy check
(``mcap_chunk.check_index``): whenever it calls an index right, the numpy check does too and
finds the same records, lengths and Schema/Channel records; an intact index is always called
right; a damaged one never is. Whole logs read the same with it and without it."""

from __future__ import annotations

import struct
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import io_loggen as gen
from accelerators import require_module

from uwval.io import mcap_raw
from uwval.io.mcap_chunk import check_index
from uwval.io.mcap_records import OP_CHANNEL, OP_MESSAGE, OP_SCHEMA
from uwval.io.raw import RawLog

require_module(mcap_raw._mcapwalk, "uwval.io._mcapwalk")

match_chunk = mcap_raw._mcapwalk.match_chunk
BASE = 1000  # the chunk's place in a batch buffer: every position out is shifted by it

#: one record: ("msg", channel, log time, payload bytes) or (opcode, content bytes)
Record = tuple


def _chunk(records: list[Record]) -> tuple[bytes, dict[int, list[tuple[int, int]]]]:
    """The records' bytes and each channel's index entries (log time, offset), file order."""
    out = bytearray()
    index: dict[int, list[tuple[int, int]]] = {}
    for r in records:
        at = len(out)
        if r[0] == "msg":
            _, cid, lt, n = r
            body = struct.pack("<HIQQ", cid, 7, lt, lt) + bytes(range(n % 256))[:n]
            out += struct.pack("<BQ", OP_MESSAGE, len(body)) + body
            index.setdefault(cid, []).append((lt, at))
        else:
            op, body = r
            out += struct.pack("<BQ", op, len(body)) + body
    return bytes(out), index


def _entries(index: dict[int, list[tuple[int, int]]]) -> dict[int, np.ndarray]:
    return {c: np.array(e, dtype=np.uint64).reshape(-1, 2) for c, e in index.items()}


def _match(
    buf: bytes, ents: dict[int, np.ndarray], want: set[int] | None = None
) -> tuple[int, np.ndarray, np.ndarray, list[tuple[int, int, int]], list[tuple[int, int, int]]]:
    groups, rows = [], 0
    for cid, e in ents.items():
        w = want is None or cid in want
        groups.append((cid, np.ascontiguousarray(e), rows if w else -1))
        rows += len(e) if w else 0
    out = np.full((rows, 3), -7, dtype=np.int64)
    spans = np.zeros((len(groups), 5), dtype=np.int64)
    tabs = np.zeros((64, 3), dtype=np.int64)
    code, n_tab = match_chunk(buf, BASE, groups, out, spans, tabs)
    return code, out, spans, [tuple(t) for t in tabs[:n_tab].tolist()], groups  # type: ignore[return-value]


def _agrees(buf: bytes, ents: dict[int, np.ndarray]) -> int:
    """Run both checks; when the C walk calls the index right, hold it to the numpy check."""
    code, out, spans, tabs, groups = _match(buf, ents)
    reason, gaps = check_index(np.frombuffer(buf, dtype=np.uint8), ents)
    if code == 0:
        assert reason == ""
        assert [(op, a + BASE, b + BASE) for op, a, b in gaps.tables] == tabs
        for g, (cid, e, row) in enumerate(groups):
            rows = out[row : row + len(e)]
            assert np.array_equal(rows[:, 0], e[:, 1].astype(np.int64) + BASE)
            assert np.array_equal(rows[:, 1], e[:, 0].astype(np.int64))
            if len(e):
                assert np.array_equal(rows[:, 2], gaps.record_lengths[cid])
                assert spans[g, :2].tolist() == [int(rows[:, 1].min()), int(rows[:, 1].max())]
                assert spans[g, 2:4].tolist() == [int(rows[:, 2].min()), int(rows[:, 2].max())]
    return code


def _records() -> st.SearchStrategy[list[Record]]:
    msg = st.tuples(
        st.just("msg"),
        st.integers(0, 5),
        st.integers(0, 2**64 - 1),
        st.integers(0, 40),
    )
    table = st.tuples(st.sampled_from([OP_SCHEMA, OP_CHANNEL, 0x0C, 0x20]), st.binary(max_size=24))
    return st.lists(st.one_of(msg, msg, table), min_size=1, max_size=30)


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(_records())
def test_an_intact_index_is_right(records: list[Record]) -> None:
    buf, index = _chunk(records)
    if not index:
        return
    assert _agrees(buf, _entries(index)) == 0


@settings(max_examples=500, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(_records(), st.data())
def test_a_changed_index_or_chunk_is_never_called_right_wrongly(
    records: list[Record], data: st.DataObject
) -> None:
    buf, index = _chunk(records)
    if not index:
        return
    ents = {c: e.copy() for c, e in _entries(index).items()}
    cid = data.draw(st.sampled_from(sorted(ents)))
    e = ents[cid]
    k = data.draw(st.integers(0, len(e) - 1))
    how = data.draw(
        st.sampled_from(
            ["offset", "time", "drop", "repeat", "swap", "unlist", "cut", "flip", "length"]
        )
    )
    b = bytearray(buf)
    if how == "offset":
        e[k, 1] += np.uint64(data.draw(st.integers(1, 40)))
    elif how == "time":
        e[k, 0] ^= np.uint64(1 << data.draw(st.integers(0, 63)))
    elif how == "drop":
        ents[cid] = np.delete(e, k, axis=0)
    elif how == "repeat":
        ents[cid] = np.insert(e, k, e[k], axis=0)
    elif how == "swap" and len(e) > 1:
        ents[cid] = e[::-1].copy()
    elif how == "unlist":
        del ents[cid]
    elif how == "cut":
        b = b[: data.draw(st.integers(0, len(b) - 1))]
    elif how == "flip":
        at = data.draw(st.integers(0, len(b) - 1))
        b[at] ^= 1 << data.draw(st.integers(0, 7))
    elif how == "length":  # a record's length field
        at = int(e[k, 1]) + 1
        struct.pack_into("<Q", b, at, data.draw(st.integers(0, 2**64 - 1)))
    if not ents:
        return
    code = _agrees(bytes(b), ents)
    # index changes the numpy check must refuse are refused by the walk too (a cut or a flip
    # can leave a valid chunk: a cut on a record boundary, a flip in a payload)
    if how in ("offset", "time", "drop", "repeat", "unlist"):
        assert code != 0


def test_unwanted_channels_are_checked_but_not_copied() -> None:
    records: list[Record] = [("msg", c, 100 + i, 8) for i in range(20) for c in (1, 2, 3)]
    records.insert(5, (OP_CHANNEL, b"\x02\x00\x01\x00abc"))
    buf, index = _chunk(records)
    ents = _entries(index)
    code, out, spans, tabs, groups = _match(buf, ents, want={2})
    assert code == 0 and out.shape == (20, 3)
    assert [row for _c, _e, row in groups] == [-1, 0, -1]
    assert spans[:, :2].tolist() == [[100, 119]] * 3
    assert tabs == [(OP_CHANNEL, BASE + 5 * 39 + 9, BASE + 5 * 39 + 9 + 7)]
    ents[3][4, 0] += np.uint64(1)  # an unwanted channel's entry is still held to its record
    assert _match(buf, ents, want={2})[0] == 5


def test_bad_buffers_are_refused_not_read() -> None:
    buf, index = _chunk([("msg", 1, 5, 8), ("msg", 1, 6, 8)])
    e = _entries(index)[1]
    spans, tabs = np.zeros((1, 5), np.int64), np.zeros((4, 3), np.int64)
    with pytest.raises(ValueError, match="out is too small"):
        match_chunk(buf, 0, [(1, e, 0)], np.zeros((1, 3), np.int64), spans, tabs)
    with pytest.raises(ValueError, match="16-byte pairs"):
        match_chunk(buf, 0, [(1, e.reshape(-1)[:3], -1)], np.zeros((0, 3), np.int64), spans, tabs)
    with pytest.raises(ValueError, match="uint16"):
        match_chunk(buf, 0, [(70000, e, -1)], np.zeros((0, 3), np.int64), spans, tabs)
    with pytest.raises(TypeError, match="int64"):
        match_chunk(buf, 0, [(1, e, 0)], np.zeros((2, 3), np.float64), spans, tabs)
    # more Schema/Channel records than the table holds: not an error, only "not confirmed"
    many, idx = _chunk([(OP_SCHEMA, b"xy")] * 5 + [("msg", 1, 5, 8)])
    code, _ = match_chunk(
        many, 0, [(1, _entries(idx)[1], 0)], np.zeros((1, 3), np.int64), spans, tabs
    )
    assert code == 7


def test_many_channels_use_the_lookup_table() -> None:
    records: list[Record] = [("msg", 1000 + c, 10 * i + c, 4) for i in range(5) for c in range(40)]
    buf, index = _chunk(records)
    assert _agrees(buf, _entries(index)) == 0
    ents = _entries(index)
    del ents[1017]
    assert _agrees(buf, ents) == 3  # a Message record of a channel the index does not list


# ---------------------------------------------------------------- whole logs, C walk on/off
def _read(
    path: Path, match: bool, monkeypatch: pytest.MonkeyPatch, *, walks: int = 10, **kw: bool
) -> RawLog:
    """Read every topic, with the C walk or without; with it, the walk must have read more
    than ``walks`` chunks."""
    monkeypatch.setattr(mcap_raw, "USE_MATCH", match)
    monkeypatch.setattr(mcap_raw, "USE_SCAN", False)  # the batched path's walk (test_mcap_scan)
    walked: list[int] = []
    from_matched = mcap_raw._Scanner._from_matched

    def counting(self: mcap_raw._Scanner, run: list, matched: list, mem: np.ndarray) -> None:
        walked.append(len(run))
        from_matched(self, run, matched, mem)

    monkeypatch.setattr(mcap_raw._Scanner, "_from_matched", counting)
    log = mcap_raw.scan_mcap(path, None, **kw)
    assert (sum(walked) > walks) == match
    return log


def _same(a: RawLog, b: RawLog) -> None:
    assert a.warnings == b.warnings and a.topics == b.topics and a.unclean == b.unclean
    assert a.raw.keys() == b.raw.keys()
    for name, ta in a.raw.items():
        tb = b.raw[name]
        assert ta.dropped == tb.dropped and np.array_equal(ta.log_time, tb.log_time), name
        assert [ta.payload(i) for i in range(len(ta))] == [tb.payload(i) for i in range(len(tb))]


@pytest.mark.parametrize("times_only", [False, True])
def test_a_log_reads_the_same_with_and_without_the_walk(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, times_only: bool
) -> None:
    path = gen.write_log(
        tmp_path / "log.mcap", "mcap", seconds=4.0, image_bytes=300, chunk_size=4096
    )
    walked = _read(path, True, monkeypatch, times_only=times_only)
    assert not walked.warnings and len(walked.raw["/gazebo/model_rov_pose"]) == 400
    _same(walked, _read(path, False, monkeypatch, times_only=times_only))


def test_a_cut_log_without_summary_reads_the_same(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """No summary: channels are first known from Channel records inside the chunks, after
    the chunk was queued (its rows are kept until then)."""
    path = gen.write_log(
        tmp_path / "log.mcap", "mcap", seconds=4.0, image_bytes=300, chunk_size=4096
    )
    data = path.read_bytes()
    path.write_bytes(data[: len(data) * 2 // 3])
    walked = _read(path, True, monkeypatch)
    assert walked.unclean and len(walked.raw["/gazebo/model_rov_pose"]) > 100
    _same(walked, _read(path, False, monkeypatch))


def test_wanted_payloads_are_copied_channel_after_channel() -> None:
    """With a payload buffer, each wanted channel's payloads lie end to end there (its rows
    then copy on as one block), channels in group order; rows give where each starts."""
    rng = np.random.default_rng(2)
    records: list[Record] = [
        ("msg", int(c), 50 + i, int(n))
        for i, (c, n) in enumerate(
            zip(rng.integers(1, 4, 90), rng.integers(0, 30, 90), strict=True)
        )
    ]
    buf, index = _chunk(records)
    ents = _entries(index)
    groups, rows = [], 0
    for cid, e in ents.items():
        groups.append((cid, e, rows if cid != 2 else -1))
        rows += len(e) if cid != 2 else 0
    out = np.zeros((rows, 3), np.int64)
    pay = np.zeros(len(buf), np.uint8)
    spans = np.zeros((3, 5), np.int64)
    code, _ = match_chunk(buf, BASE, groups, out, spans, np.zeros((4, 3), np.int64), pay, 77)
    assert code == 0
    for g, (_cid, e, row) in enumerate(groups):  # where each wanted channel's payloads start
        assert spans[g, 4] == (out[row, 0] if row >= 0 else -1)
        if row >= 0:
            lengths = out[row : row + len(e), 2]
            assert spans[g, 2:4].tolist() == [int(lengths.min()), int(lengths.max())]
    data = np.frombuffer(buf, np.uint8)
    at = 77
    for _cid, e, row in groups:
        if row < 0:
            continue
        for j, (_lt, off) in enumerate(e.tolist()):
            start, _t, rl = out[row + j].tolist()
            assert start == at  # end to end, channel after channel
            assert (
                pay[start - 77 : start - 77 + rl - 22].tobytes()
                == data[off + 31 : off + 9 + rl].tobytes()
            )
            at += rl - 22
    # a payload buffer too small for them is "not confirmed", never an overrun
    small = np.zeros(5, np.uint8)
    code, _ = match_chunk(
        buf, BASE, groups, out, np.zeros((3, 5), np.int64), np.zeros((4, 3), np.int64), small, 0
    )
    assert code == 8 and not small.any()


def test_take_rows_copies_blocks_and_scattered_rows_alike() -> None:
    from uwval.io.raw import TopicBuilder

    rng = np.random.default_rng(4)
    buf = rng.integers(0, 256, 4000, dtype=np.uint8)
    blocks = np.concatenate([np.arange(10) * 8, 200 + np.arange(30) * 8, [900, 1000]])
    scattered = np.sort(rng.choice(3900, 60, replace=False))
    for starts in (blocks, scattered):
        a = TopicBuilder("/t", "x/msg/Y", "cdr")
        a.reserve(len(starts), 1 << 20)
        a.take_rows(buf, starts.astype(np.int64), 8, np.arange(len(starts), dtype=np.int64))
        got = a.build()
        assert [got.payload(i) for i in range(len(starts))] == [
            buf[s : s + 8].tobytes() for s in starts
        ]


def _lone_reads(monkeypatch: pytest.MonkeyPatch) -> list[int]:
    """The record starts of the chunks read alone (``_Scanner.chunk``) from now on."""
    alone: list[int] = []
    lone = mcap_raw._Scanner.chunk

    def counting(self: mcap_raw._Scanner, rec: int, *a: object) -> None:
        alone.append(rec)
        lone(self, rec, *a)  # type: ignore[arg-type]

    monkeypatch.setattr(mcap_raw._Scanner, "chunk", counting)
    return alone


def test_an_index_out_of_file_order_is_left_to_the_numpy_check(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A MessageIndex listing its channel's records out of file order is still right (the
    numpy check sorts them): the walk does not confirm it, the chunk is read alone, and the
    log reads as without the walk, with no warning."""
    from mcap.reader import make_reader

    path = gen.write_log(tmp_path / "log.mcap", "mcap", seconds=4.0, image_bytes=0, chunk_size=4096)
    with open(path, "rb") as fh:
        summary = make_reader(fh).get_summary()
    assert summary is not None
    data = bytearray(path.read_bytes())
    chunk = summary.chunk_indexes[len(summary.chunk_indexes) // 2]
    at = max(chunk.message_index_offsets.values()) + 9 + 2 + 4  # the entries of one channel
    first, second = bytes(data[at : at + 16]), bytes(data[at + 16 : at + 32])
    data[at : at + 16], data[at + 16 : at + 32] = second, first
    path.write_bytes(bytes(data))
    alone = _lone_reads(monkeypatch)
    walked = _read(path, True, monkeypatch)
    assert alone == [chunk.chunk_start_offset] and not walked.warnings
    _same(walked, _read(path, False, monkeypatch))


def test_a_chunk_with_more_channel_records_than_the_walk_takes(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """More Schema/Channel records in one chunk than the walk's table holds: that chunk is
    read alone (numpy), the others by the walk, and the log reads as without the walk."""
    from mcap.writer import Writer

    path = tmp_path / "many.mcap"
    with open(path, "wb") as fh:
        w = Writer(fh, chunk_size=64 * 1024)
        w.start(profile="", library="uwval-tests")
        sid = w.register_schema(name="raw", encoding="", data=b"")
        chans = [
            w.register_channel(topic=f"/t{k}", message_encoding="raw", schema_id=sid)
            for k in range(mcap_raw.MATCH_TABLES + 40)
        ]
        for i in range(3000):
            w.add_message(chans[i % len(chans)], log_time=i, publish_time=i, data=bytes(12))
        w.finish()
    alone = _lone_reads(monkeypatch)
    walked = _read(path, True, monkeypatch, walks=0)
    assert len(alone) == 1  # the chunk holding the Channel records, read alone
    assert not walked.warnings and len(walked.raw) == mcap_raw.MATCH_TABLES + 40
    _same(walked, _read(path, False, monkeypatch))
