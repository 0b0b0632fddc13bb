"""The C run reader of MCAP logs (``_mcapwalk.scan_chunks``, used by
:mod:`uwval.io.mcap_raw`): whatever it reads, it reads exactly as the batched path does, and
whatever it leaves to that path (damaged chunks, Schema/Channel records it does not know,
Metadata records between chunks, lz4 or unindexed chunks, oversized chunks) is read there,
in file order. The reference of every comparison is the chunk-by-chunk numpy read."""

from __future__ import annotations

import os
import random
import sys
import zlib
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import io_loggen as gen

from uwval.errors import LogReadError
from uwval.io import mcap_raw, mcap_runs
from uwval.io.raw import RawLog

TOPICS = ["/gazebo/model_rov_pose", "/unity/model_rov_pose", "/tf", "/camera/image_raw/compressed"]


@pytest.fixture(autouse=True)
def scan_ready() -> None:
    if mcap_raw._mcapwalk is None or not mcap_runs.scan_ready():
        if os.environ.get("UWVAL_REQUIRE_ACCELERATOR"):
            pytest.fail("the C run reader is not available (UWVAL_REQUIRE_ACCELERATOR is set)")
        pytest.skip("no C run reader here (uwval.io._mcapwalk or libzstd.so.1 missing)")


class Counted:
    """``scan_chunks`` with a record of the runs it read: (stop reason, chunks read) each
    (``calls``), and of how many runs each call returned (``per_call``)."""

    def __init__(self, monkeypatch: pytest.MonkeyPatch) -> None:
        assert mcap_raw._mcapwalk is not None
        self.calls: list[tuple[int, int]] = []
        self.per_call: list[int] = []
        real = mcap_raw._mcapwalk.scan_chunks

        def counted(*args: Any) -> Any:
            out = real(*args)
            runs = out[0] if isinstance(out[0], list) else [out]
            self.calls += [(r[0], r[2]) for r in runs]
            self.per_call.append(len(runs))
            return out

        monkeypatch.setattr(mcap_raw._mcapwalk, "scan_chunks", counted)

    @property
    def chunks(self) -> int:
        return sum(n for _stop, n in self.calls)


def _read(
    path: Path, monkeypatch: pytest.MonkeyPatch, *, scan: bool, topics: Any = TOPICS, **kw: Any
) -> RawLog | str:
    """The log read with the C runs or chunk by chunk with numpy (or the error's text)."""
    with monkeypatch.context() as m:
        m.setattr(mcap_raw, "USE_SCAN", scan)
        if not scan:
            m.setattr(mcap_raw, "USE_MATCH", False)
            m.setattr(mcap_raw, "BATCH_BYTES", 0)
        try:
            return mcap_raw.scan_mcap(path, topics, **kw)
        except LogReadError as exc:
            return f"LogReadError: {exc}"


def _same(a: RawLog | str, b: RawLog | str) -> None:
    if isinstance(a, str) or isinstance(b, str):
        assert a == b
        return
    assert a.warnings == b.warnings
    assert a.topics == b.topics
    assert (a.unclean, a.lost_bytes, a.cut_detail) == (b.unclean, b.lost_bytes, b.cut_detail)
    assert a.raw.keys() == b.raw.keys()
    for name, ta in a.raw.items():
        tb = b.raw[name]
        assert (ta.msgtype, ta.encoding, ta.dropped) == (tb.msgtype, tb.encoding, tb.dropped)
        assert np.array_equal(ta.log_time, tb.log_time), name
        assert np.array_equal(ta.length, tb.length), name
        assert [ta.payload(i) for i in range(len(ta))] == [tb.payload(i) for i in range(len(tb))]


def _write(
    path: Path,
    *,
    seconds: float = 4.0,
    compression: str = "zstd",
    chunk_size: int = 4096,
    summary_tables: bool = True,
    metadata_every: int = 0,
    indexed: bool = True,
    seed: int = 0,
) -> Path:
    """An interleaved log (io_loggen's messages) with the writer options the tests vary."""
    from mcap.writer import CompressionType, IndexType, Writer

    ts = gen._store(2)
    comp = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4, "none": CompressionType.NONE}
    with open(path, "wb") as fh:
        w = Writer(
            fh,
            chunk_size=chunk_size,
            compression=comp[compression],
            repeat_channels=summary_tables,
            repeat_schemas=summary_tables,
            index_types=IndexType.ALL if indexed else IndexType.NONE,
        )
        w.start(profile="ros2", library="uwval-tests")
        schemas: dict[str, int] = {}
        chans: dict[str, int] = {}
        for k, (t, topic, typ, msg) in enumerate(gen._messages(seconds, 500, 2, seed)):
            if typ not in schemas:
                text, _ = ts.generate_msgdef(typ, ros_version=2)
                schemas[typ] = w.register_schema(name=typ, encoding="ros2msg", data=text.encode())
            if topic not in chans:
                chans[topic] = w.register_channel(
                    topic=topic, message_encoding="cdr", schema_id=schemas[typ]
                )
            w.add_message(
                chans[topic], log_time=t, publish_time=t, data=bytes(ts.serialize_cdr(msg, typ))
            )
            if metadata_every and k % metadata_every == metadata_every - 1:
                w.add_metadata(f"m{k}", {"k": str(k)})
        w.finish()
    return path


@pytest.mark.parametrize("mapped", [False, True])
def test_a_runs_buffers_are_its_own_memory_read_only(tmp_path: Path, mapped: bool) -> None:
    """The rows, payloads and table a run hands back are ``Held`` buffers over the C call's
    memory (no copy into bytes; page-mapped when large for a workspace made ``mapped``):
    read-only, as long as their contents, and they outlive the call; the rows point into
    the payloads, record by record."""
    import mmap

    log = _write(tmp_path / "log.mcap")
    mod = mcap_raw._mcapwalk
    assert mod is not None
    with open(log, "rb") as fh, mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ) as mm:
        plan = mcap_runs.plan_early(mm, {"/gazebo/model_rov_pose"})
        assert plan is not None
        pos, end, maps = plan
        runs, _released = mod.scan_chunks(
            mod.scan_workspace(mapped), mm, pos, end, maps, 1 << 20, 1 << 20, 2, True,
            1 << 26, 0, 0, True,
        )  # fmt: skip
    _stop, _nxt, n, rows, packed, stats = runs[0]
    assert n > 0 and all(isinstance(b, mod.Held) for b in (rows, packed, stats))
    per = np.frombuffer(stats, np.int64).reshape(-1, 9)
    recs = np.frombuffer(rows, np.int64).reshape(-1, 3)
    assert len(rows) == recs.size * 8 and len(stats) == per.size * 8
    assert len(packed) == int((recs[:, 2] - 22).sum())  # the wanted payloads, end to end
    assert len(packed) > 16 << 10  # large enough to be page-mapped when asked
    view = memoryview(packed)
    assert view.readonly
    with pytest.raises(TypeError):
        view[0] = 1
    # each record's payload starts where the one before it ended (one channel wanted)
    assert np.array_equal(recs[1:, 0], recs[:-1, 0] + recs[:-1, 2] - 22)


@given(st.binary(max_size=5000), st.integers(0, 64))
@settings(max_examples=200, deadline=None)
def test_its_crc32_is_zlibs(data: bytes, cut: int) -> None:
    assert mcap_raw._mcapwalk is not None
    assert mcap_raw._mcapwalk.crc32(data) == zlib.crc32(data)
    assert mcap_raw._mcapwalk.crc32(data[cut:]) == zlib.crc32(data[cut:])


@pytest.mark.parametrize("compression", ["zstd", "none"])
@pytest.mark.parametrize("topics", ["selected", "all", "times"])
def test_runs_read_what_single_chunks_read(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, compression: str, topics: str
) -> None:
    log = _write(tmp_path / "log.mcap", compression=compression)
    counted = Counted(monkeypatch)
    kw: dict[str, Any] = {"topics": None if topics == "all" else TOPICS[:2]}
    kw["times_only"] = topics == "times"
    monkeypatch.setattr(mcap_raw, "SCAN_FILE_BYTES", 16_000)  # many runs
    got = _read(log, monkeypatch, scan=True, **kw)
    assert isinstance(got, RawLog) and not got.warnings
    assert len(counted.calls) > 5 and counted.chunks > 20
    assert all(stop in (1, 2) for stop, _n in counted.calls)  # budget, then DataEnd
    assert counted.per_call == [len(counted.calls)]  # each run planned as the last was read
    _same(got, _read(log, monkeypatch, scan=False, **kw))
    assert len(got.raw["/gazebo/model_rov_pose"]) == 400


@pytest.mark.parametrize("hold", [1, 30_000])
def test_calls_that_return_every_few_runs_read_the_same(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, hold: int
) -> None:
    """Calls that return once ``hold`` bytes of results are held (the reader adds them, then
    calls again from the next run) read what one call for the whole log reads."""
    log = _write(tmp_path / "log.mcap")
    monkeypatch.setattr(mcap_raw, "SCAN_FILE_BYTES", 16_000)  # many runs
    whole = _read(log, monkeypatch, scan=True)
    counted = Counted(monkeypatch)
    monkeypatch.setattr(mcap_raw, "SCAN_HOLD_BYTES", hold)
    got = _read(log, monkeypatch, scan=True)
    assert len(counted.per_call) > 3 and counted.chunks > 20
    if hold == 1:
        assert set(counted.per_call) == {1}  # every run returned at once
    else:
        assert max(counted.per_call) > 1
    _same(got, whole)
    _same(got, _read(log, monkeypatch, scan=False))


@pytest.mark.parametrize("threads", [1, 2, 5])
def test_any_number_of_threads_reads_the_same(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, threads: int
) -> None:
    log = _write(tmp_path / "log.mcap", seconds=6.0)
    real = mcap_raw._Scanner._scan

    def with_threads(self: mcap_raw._Scanner, pos: int, end: int) -> int | None:
        self.scan_threads = threads
        return real(self, pos, end)

    monkeypatch.setattr(mcap_raw._Scanner, "_scan", with_threads)
    _same(_read(log, monkeypatch, scan=True), _read(log, monkeypatch, scan=False))


def test_chunks_naming_channels_the_summary_does_not_are_left_to_the_batched_path(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Without Schema/Channel records in the summary, the chunks that first name a channel
    are read by the batched path (in file order); the C runs read the others."""
    log = _write(tmp_path / "log.mcap", summary_tables=False)
    counted = Counted(monkeypatch)
    got = _read(log, monkeypatch, scan=True)
    assert any(stop == 3 for stop, _n in counted.calls)  # a chunk left to the batched path
    assert counted.chunks > 20
    _same(got, _read(log, monkeypatch, scan=False))


def test_metadata_between_chunks_is_read_in_file_order(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    log = _write(tmp_path / "log.mcap", metadata_every=97)
    counted = Counted(monkeypatch)
    got = _read(log, monkeypatch, scan=True)
    assert sum(stop == 1 for stop, _n in counted.calls) > 3  # stopped at each Metadata record
    assert counted.chunks > 20
    _same(got, _read(log, monkeypatch, scan=False))


@pytest.mark.parametrize("kind", ["lz4", "unindexed"])
def test_chunks_it_never_reads_stop_it_for_the_rest_of_the_file(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, kind: str
) -> None:
    if kind == "lz4":
        log = _write(tmp_path / "log.mcap", compression="lz4")
    else:
        log = _write(tmp_path / "log.mcap", indexed=False)
    counted = Counted(monkeypatch)
    got = _read(log, monkeypatch, scan=True)
    assert counted.calls == [(4, 0)]  # asked once, then never again
    _same(got, _read(log, monkeypatch, scan=False))


def test_a_chunk_larger_than_a_batch_is_read_alone_and_the_runs_go_on(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    log = _write(tmp_path / "log.mcap")
    from mcap.reader import make_reader

    with open(log, "rb") as fh:
        summary = make_reader(fh).get_summary()
    assert summary is not None
    sizes = sorted(c.uncompressed_size for c in summary.chunk_indexes)
    monkeypatch.setattr(mcap_raw, "BATCH_MAX", sizes[len(sizes) // 2])
    counted = Counted(monkeypatch)
    got = _read(log, monkeypatch, scan=True)
    assert sum(stop == 3 for stop, _n in counted.calls) > 5 and counted.chunks > 5
    _same(got, _read(log, monkeypatch, scan=False))


@pytest.mark.parametrize("compression", ["zstd", "none"])
def test_damaged_logs_read_as_the_batched_path_reads_them(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, compression: str
) -> None:
    """Differential fuzz: byte flips and zeroed runs anywhere in the file (chunk headers,
    compressed records, indexes, the summary) give the same messages, drops, warnings and
    errors with the C runs as chunk by chunk with numpy."""
    base = _write(tmp_path / "base.mcap", compression=compression).read_bytes()
    rng = random.Random(int(os.environ.get("UWVAL_SCAN_FUZZ_SEED", "7")))
    damaged = tmp_path / "damaged.mcap"
    left_to_batched = 0
    counted = Counted(monkeypatch)
    for _case in range(int(os.environ.get("UWVAL_SCAN_FUZZ_N", "60"))):
        data = bytearray(base)
        for _ in range(rng.randint(1, 4)):
            at = rng.randrange(len(data))
            if rng.random() < 0.7:
                data[at] ^= 1 << rng.randrange(8)
            else:
                n = rng.randint(2, 40)
                data[at : at + n] = bytes(len(data[at : at + n]))
        damaged.write_bytes(bytes(data))
        counted.calls.clear()
        got = _read(damaged, monkeypatch, scan=True)
        left_to_batched += sum(stop == 3 for stop, _n in counted.calls)
        _same(got, _read(damaged, monkeypatch, scan=False))
    assert left_to_batched > 5  # the damage reached chunks the C runs handed over


def test_without_libzstd_the_batched_path_reads_the_same(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """setup_codecs finding no libzstd (a machine without it): no C runs, same result."""
    log = _write(tmp_path / "log.mcap")
    with_runs = _read(log, monkeypatch, scan=True)
    monkeypatch.setattr(mcap_runs, "_codecs", [False])
    counted = Counted(monkeypatch)
    without = _read(log, monkeypatch, scan=True)
    assert counted.calls == []
    _same(without, with_runs)
