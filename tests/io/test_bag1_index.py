"""The C check of ROS 1 IndexData entries (``uwval.io._bag1index.locate``) agrees with the
Python one (``bag1_raw._index_ok``): whenever it confirms the entries, the Python check does
too and the data places it returns are the records' own; intact entries are always
confirmed; changed ones never wrongly. Whole bags read the same with it and without it."""

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

from uwval.io import bag1_raw

require_module(bag1_raw._bag1index, "uwval.io._bag1index")

locate = bag1_raw._bag1index.locate


def _field(name: bytes, value: bytes) -> bytes:
    return struct.pack("<I", len(name) + 1 + len(value)) + name + b"=" + value


def _message(conn: int, sec: int, nsec: int, data: bytes, extra: list[bytes]) -> bytes:
    fields = [
        _field(b"op", b"\x02"),
        _field(b"conn", struct.pack("<I", conn)),
        _field(b"time", struct.pack("<II", sec, nsec)),
        *extra,
    ]
    header = b"".join(fields)
    return struct.pack("<I", len(header)) + header + struct.pack("<I", len(data)) + data


def _chunk(msgs: list[tuple]) -> tuple[bytes, dict[int, np.ndarray]]:
    out = bytearray()
    index: dict[int, list[tuple[int, int, int]]] = {}
    for conn, sec, nsec, n, order in msgs:
        extra = [_field(b"callerid", b"/node")] if order else []
        if order == 2:  # fields in another order, as some writers put them
            header = (
                _field(b"time", struct.pack("<II", sec, nsec))
                + _field(b"conn", struct.pack("<I", conn))
                + _field(b"op", b"\x02")
            )
            rec = struct.pack("<I", len(header)) + header + struct.pack("<I", n) + bytes(n)
        else:
            rec = _message(conn, sec, nsec, bytes(range(n % 256))[:n], extra)
        index.setdefault(conn, []).append((sec, nsec, len(out)))
        out += rec
        if conn == 3:  # a connection record between messages
            h = _field(b"op", b"\x07") + _field(b"conn", struct.pack("<I", 3))
            out += struct.pack("<I", len(h)) + h + struct.pack("<I", 0)
    return bytes(out), {c: np.array(e, dtype="<u4").reshape(-1, 3) for c, e in index.items()}


def _msgs() -> st.SearchStrategy[list[tuple]]:
    one = st.tuples(
        st.integers(0, 3),
        st.integers(0, 2**32 - 1),
        st.integers(0, 999_999_999),
        st.integers(0, 70),
        st.integers(0, 2),
    )
    return st.lists(one, min_size=1, max_size=25)


def _agrees(buf: bytes, cid: int, e: np.ndarray) -> bool:
    out = np.zeros((len(e), 2), np.int64)
    ok = locate(buf, cid, np.ascontiguousarray(e), out)
    data = np.frombuffer(buf, dtype=np.uint8)
    if ok:
        assert bag1_raw._index_ok(data, cid, e)
        for (_s, _n, off), (ds, dl) in zip(e.tolist(), out.tolist(), strict=True):
            _h, pds, pdl, _nxt = bag1_raw._record(data, off, len(buf))
            assert (ds, dl) == (pds, pdl)
    return bool(ok)


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(_msgs())
def test_intact_entries_are_confirmed(msgs: list[tuple]) -> None:
    buf, index = _chunk(msgs)
    for cid, e in index.items():
        assert _agrees(buf, cid, e)


@settings(max_examples=500, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(_msgs(), st.data())
def test_changed_entries_or_records_are_never_confirmed_wrongly(
    msgs: list[tuple], data: st.DataObject
) -> None:
    buf, index = _chunk(msgs)
    cid = data.draw(st.sampled_from(sorted(index)))
    e = index[cid].copy()
    k = data.draw(st.integers(0, len(e) - 1))
    how = data.draw(st.sampled_from(["offset", "sec", "nsec", "conn", "flip", "cut"]))
    b = bytearray(buf)
    if how == "offset":
        e[k, 2] += np.uint32(data.draw(st.integers(1, 30)))
    elif how in ("sec", "nsec"):
        e[k, 0 if how == "sec" else 1] ^= np.uint32(1 << data.draw(st.integers(0, 31)))
    elif how == "conn":
        cid = cid + 1
    elif how == "flip":
        at = data.draw(st.integers(0, len(b) - 1))
        b[at] ^= 1 << data.draw(st.integers(0, 7))
    else:
        b = b[: data.draw(st.integers(0, len(b) - 1))]
    ok = _agrees(bytes(b), cid, e)
    if how in ("sec", "nsec", "conn"):
        assert not ok


def test_headers_it_does_not_take_are_left_to_python() -> None:
    rec = _message(1, 5, 6, b"abcd", [_field(b"time", struct.pack("<II", 5, 6))])
    e = np.array([[5, 6, 0]], dtype="<u4")
    out = np.zeros((1, 2), np.int64)
    assert not locate(rec, 1, e, out)  # time repeated: declined
    accented = _message(1, 5, 6, b"abcd", [_field("caller\u00e9".encode(), b"x")])
    assert not locate(accented, 1, e, out)  # a field name not ASCII: declined
    with pytest.raises(ValueError, match="12-byte"):
        locate(rec, 1, np.zeros(5, np.uint8), out)
    with pytest.raises(ValueError, match="int64"):
        locate(rec, 1, e, np.zeros((1, 2), np.float64))


@pytest.mark.parametrize("compression", ["none", "bz2", "lz4"])
def test_a_bag_reads_the_same_with_and_without_the_check(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, compression: str
) -> None:
    path = gen.write_log(tmp_path / "log.bag", "bag", seconds=3.0, compression=compression)
    logs = []
    for on in (True, False):
        monkeypatch.setattr(bag1_raw, "USE_LOCATE", on)
        calls: list[bool] = []
        real = bag1_raw._bag1index.locate

        def counting(*a: object, _real: object = real, _calls: list[bool] = calls) -> bool:
            _calls.append(True)
            return _real(*a)  # type: ignore[operator, no-any-return]

        monkeypatch.setattr(bag1_raw._bag1index, "locate", counting)
        logs.append(bag1_raw.scan_bag1(path, None))
        assert bool(calls) == on
    a, b = logs
    assert a.topics == b.topics and a.warnings == b.warnings and not a.warnings
    for name, ta in a.raw.items():
        tb = b.raw[name]
        assert np.array_equal(ta.log_time, tb.log_time) and ta.dropped == tb.dropped
        assert [ta.payload(i) for i in range(len(ta))] == [tb.payload(i) for i in range(len(tb))]
