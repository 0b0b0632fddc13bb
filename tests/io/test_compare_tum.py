"""TUM text reader/writer: exact stamps, repairs, and errors that name the line."""

from __future__ import annotations

import os
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import uwval.io.tum as tum_module
from uwval.errors import LogReadError, PoseStreamError
from uwval.io.tum import ns_from_seconds, read_tum, seconds_from_ns, write_tum
from uwval.posestream import PoseStream
from uwval.rotations import quat_from_rpy

#: Set (as .ci/run does) to fail instead of skip when the C accelerator was not built.
REQUIRE_ACCELERATOR = bool(os.environ.get("UWVAL_REQUIRE_ACCELERATOR"))


@pytest.fixture(
    autouse=True,
    scope="module",
    params=[pytest.param(True, id="c-accelerator"), pytest.param(False, id="loadtxt")],
)
def tum_engine(request: pytest.FixtureRequest) -> Iterator[bool]:
    """Every test of this file runs with the C accelerator and with numpy's loadtxt path."""
    if request.param and tum_module._tumparse is None:
        if REQUIRE_ACCELERATOR:
            pytest.fail("uwval.io._tumparse was not built (UWVAL_REQUIRE_ACCELERATOR is set)")
        pytest.skip("the C accelerator uwval.io._tumparse is not built here")
    saved = tum_module.USE_ACCELERATOR
    tum_module.USE_ACCELERATOR = request.param
    yield request.param
    tum_module.USE_ACCELERATOR = saved


def test_parses_comments_and_values(tmp_path: Path) -> None:
    f = tmp_path / "a.tum"
    f.write_text("# header\n1.5 1 2 3 0 0 0 1\n  # indented comment\n2.25 4 5 6 0 0 1 0\n\n")
    s = read_tum(f)
    assert s.t.tolist() == [1_500_000_000, 2_250_000_000]
    np.testing.assert_array_equal(s.position, [[1, 2, 3], [4, 5, 6]])
    np.testing.assert_array_equal(s.orientation, [[0, 0, 0, 1], [0, 0, 1, 0]])
    assert s.frame == "enu"
    assert s.source == str(f)


def test_bad_line_is_named_with_byte_offset(tmp_path: Path) -> None:
    f = tmp_path / "bad.txt"
    f.write_text("# c\n1.0 0 0 0 0 0 0 1\n2.0 0 0 0 0 0 1\n")
    with pytest.raises(LogReadError, match=r"bad.txt: line 3 \(byte offset 22\): expected 8"):
        read_tum(f)
    f.write_text("1.0 0 0 0 0 0 0 1\n2.0 0 0 x 0 0 0 1\n")
    with pytest.raises(LogReadError, match="line 2"):
        read_tum(f)


def test_missing_and_empty_files(tmp_path: Path) -> None:
    with pytest.raises(LogReadError, match="no such file"):
        read_tum(tmp_path / "nope.tum")
    (tmp_path / "e.tum").write_text("# only a comment\n")
    with pytest.raises(LogReadError, match="no poses"):
        read_tum(tmp_path / "e.tum")


def test_nan_is_rejected_naming_the_sample(tmp_path: Path) -> None:
    f = tmp_path / "n.tum"
    f.write_text("1 0 0 0 0 0 0 1\n2 nan 0 0 0 0 0 1\n")
    with pytest.raises(PoseStreamError, match="sample 1"):
        read_tum(f)


def test_unsorted_and_duplicate_stamps_are_repaired_and_counted(tmp_path: Path) -> None:
    f = tmp_path / "u.tum"
    f.write_text("3 0 0 0 0 0 0 1\n1 0 0 0 0 0 0 1\n2 0 0 0 0 0 0 1\n2 9 9 9 0 0 0 1\n")
    s = read_tum(f)
    assert s.t.tolist() == [1_000_000_000, 2_000_000_000, 3_000_000_000]
    assert s.repairs["sorted"] == 1
    assert s.repairs["duplicates_dropped"] == 1


@settings(max_examples=300, deadline=None)
@given(st.integers(0, 4 * 10**18))
def test_seconds_ns_round_trip_is_exact_for_decimal_stamps(ns: int) -> None:
    # a stamp written with <= 9 decimals: the double evo parses comes back bit for bit, so
    # evo-style association on seconds sees the same numbers as evo
    x = float(f"{ns // 10**9}.{ns % 10**9:09d}")
    assert seconds_from_ns(ns_from_seconds(np.array([x])))[0] == x


@settings(max_examples=300, deadline=None)
@given(st.floats(2.0**24, 4e9, allow_nan=False))
def test_seconds_ns_round_trip_is_exact_for_epoch_doubles(x: float) -> None:
    # any double past 2^24 s (ulp > 1 ns, e.g. Unix epoch stamps) survives the int64 ns trip
    assert seconds_from_ns(ns_from_seconds(np.array([x])))[0] == x


def test_epoch_stamps_keep_their_text_double(tmp_path: Path) -> None:
    f = tmp_path / "e.tum"
    f.write_text("1305031102.175304 0 0 0 0 0 0 1\n1305031102.211214 0 0 0 0 0 0 1\n")
    s = read_tum(f)
    assert seconds_from_ns(s.t).tolist() == [1305031102.175304, 1305031102.211214]


def test_write_read_round_trip(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    n = 50
    t = 1_700_000_000_000_000_000 + np.cumsum(rng.integers(1, 10**8, n))
    s = PoseStream.from_arrays(t, rng.normal(size=(n, 3)), quat_from_rpy(rng.normal(size=(n, 3))))
    write_tum(tmp_path / "w.tum", s)
    back = read_tum(tmp_path / "w.tum")
    # stamps with 9 decimals: exact only up to the double's resolution at 1.7e9 s (~240 ns)
    assert np.abs(back.t - s.t).max() < 300
    np.testing.assert_allclose(back.position, s.position, atol=1e-9)
    np.testing.assert_allclose(back.orientation, s.orientation, atol=1e-9)


def test_seven_plus_nine_numbers_is_not_silently_misparsed(tmp_path: Path) -> None:
    f = tmp_path / "s.tum"
    f.write_text("1 0 0 0 0 0 0 1\n2 0 0 0 0 0 1\n3 0 0 0 0 0 0 1 0\n4 0 0 0 0 0 0 1\n")
    with pytest.raises(LogReadError, match="line 2"):
        read_tum(f)


def test_seven_plus_nine_with_comments_further_down_is_named_too(tmp_path: Path) -> None:
    f = tmp_path / "s.tum"
    f.write_text(
        "1 0 0 0 0 0 0 1\n# a comment mid-file\n2 0 0 0 0 0 1\n3 0 0 0 0 0 0 1 0\n4 0 0 0 0 0 0 1\n"
    )
    with pytest.raises(LogReadError, match="line 3"):
        read_tum(f)


def _rounded_tum(path: Path, n: int, decimals: int, comment_mid: bool = False) -> PoseStream:
    """A TUM file whose quaternions are rounded to ``decimals`` places (not unit to 1e-9)."""
    rng = np.random.default_rng(7)
    q = quat_from_rpy(rng.uniform(-3, 3, (n, 3)))
    t = 1_700_000_000 + np.arange(n) * 0.01
    pos = rng.normal(0, 5, (n, 3))
    fmt = f"%.4f %.{decimals}f %.{decimals}f %.{decimals}f " + " ".join([f"%.{decimals}f"] * 4)
    lines = [fmt % (t[i], *pos[i], *q[i]) for i in range(n)]
    if comment_mid:
        lines.insert(n // 2, "# resumed")
    path.write_text("# timestamp tx ty tz qx qy qz qw\n" + "\n".join(lines) + "\n")
    table = np.loadtxt(path, comments="#")
    return PoseStream.from_arrays(
        ns_from_seconds(table[:, 0]), table[:, 1:4], table[:, 4:8], topic="tum", source=str(path)
    )


@pytest.mark.parametrize("comment_mid", [False, True])
@pytest.mark.parametrize("decimals", [4, 6])
def test_rounded_quaternions_are_normalised_without_the_per_line_search(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, decimals: int, comment_mid: bool
) -> None:
    """Real TUM files (4-6 decimal quaternions) stay on the vectorised path: same numbers and
    the same ``repairs`` count as PoseStream.from_arrays, and the per-line Python search for
    a bad line never runs (it would raise here)."""
    f = tmp_path / "gt.tum"
    want = _rounded_tum(f, 3000, decimals, comment_mid)
    assert want.repairs.get("renormalized", 0) > 0

    def forbidden(*args: object, **kwargs: object) -> str:
        raise AssertionError("_first_bad_line ran on a well-formed file")

    monkeypatch.setattr(tum_module, "_first_bad_line", forbidden)
    got = read_tum(f)
    assert got.repairs == want.repairs
    assert np.array_equal(got.t, want.t)
    assert np.array_equal(got.position, want.position)
    assert np.array_equal(got.orientation, want.orientation)  # bit for bit
    norms = np.linalg.norm(got.orientation, axis=1)
    assert np.abs(norms - 1.0).max() < 1e-12


def test_badly_non_unit_quaternion_is_still_refused(tmp_path: Path) -> None:
    f = tmp_path / "s.tum"
    f.write_text("1 0 0 0 0 0 0 1\n2 0 0 0 0 0 0 0.9\n")
    with pytest.raises(PoseStreamError, match=r"sample 1 has norm 0\.9"):
        read_tum(f)


def test_large_file_is_parsed_in_chunks(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import uwval.io.tum as tum

    monkeypatch.setattr(tum, "_CHUNK", 64)  # force many chunks and boundary cases
    rng = np.random.default_rng(2)
    n = 300
    s = PoseStream.from_arrays(
        np.arange(n, dtype=np.int64) * 10_000_000 + 5,
        rng.normal(size=(n, 3)),
        quat_from_rpy(rng.normal(size=(n, 3))),
    )
    write_tum(tmp_path / "c.tum", s)
    back = read_tum(tmp_path / "c.tum")
    np.testing.assert_array_equal(back.t, s.t)
    np.testing.assert_allclose(back.position, s.position, atol=1e-9)
    (tmp_path / "c.tum").write_text((tmp_path / "c.tum").read_text() + "1e99 1 2\n")
    with pytest.raises(LogReadError, match=f"line {n + 2}"):
        read_tum(tmp_path / "c.tum")


# ---- the block parser: bit-exact against float(), whatever the layout -----------------------

_FORMATS = (
    repr,
    "{:.9f}".format,
    "{:.17g}".format,
    "{:.3e}".format,
    "{:+.6f}".format,
    lambda x: str(round(x)),
)
_value = st.floats(-1e6, 1e6, allow_nan=False, allow_infinity=False)
_stamp = st.floats(0.0, 4e9, allow_nan=False, allow_infinity=False)


@st.composite
def _tum_text(draw: st.DrawFn) -> tuple[str, list[list[str]]]:
    """TUM text with random number formats, separators, line endings, comments, blank lines."""
    n = draw(st.integers(1, 30))
    newline = draw(st.sampled_from(["\n", "\r\n"]))
    lines, tokens = [], []
    for _ in range(n):
        if draw(st.booleans()) and draw(st.booleans()):
            lines.append(draw(st.sampled_from(["# comment", "", "   ", "#"])))
        row = [draw(st.sampled_from(_FORMATS))(draw(_stamp))]
        row += [draw(st.sampled_from(_FORMATS))(draw(_value)) for _ in range(7)]
        seps = [draw(st.sampled_from([" ", "\t", "  ", " \t"])) for _ in range(7)]
        lines.append("".join(tok + sep for tok, sep in zip(row, [*seps, ""], strict=True)))
        tokens.append(row)
    return newline.join(lines) + draw(st.sampled_from(["", newline])), tokens


@settings(max_examples=150, deadline=None)
@given(_tum_text(), st.sampled_from([64, 200, 1 << 18]))
def test_block_parser_equals_float_bit_for_bit(
    tmp_path_factory: pytest.TempPathFactory, case: tuple[str, list[list[str]]], chunk: int
) -> None:
    import uwval.io.tum as tum

    text, tokens = case
    f = tmp_path_factory.mktemp("tum") / "h.tum"
    f.write_bytes(text.encode())
    expected = np.array([[float(tok) for tok in row] for row in tokens])
    old = tum._CHUNK
    tum._CHUNK = chunk  # small blocks: lines cut at every possible place
    try:
        table = tum.parse_tum_file(f)
        t, pose = tum._read_columns(f)
    finally:
        tum._CHUNK = old
    assert table.view(np.int64).tolist() == expected.view(np.int64).tolist()
    assert t.tolist() == ns_from_seconds(expected[:, 0]).tolist()
    assert pose.view(np.int64).tolist() == expected[:, 1:].view(np.int64).tolist()


def test_block_parser_matches_numpy_loadtxt_on_a_large_clean_file(tmp_path: Path) -> None:
    # many blocks of the fast path (no comments), compared with np.loadtxt on the whole text
    rng = np.random.default_rng(5)
    n = 20_000
    t = 1_700_000_000_000_000_000 + np.arange(n, dtype=np.int64) * 10**7
    s = PoseStream.from_arrays(
        t, rng.normal(size=(n, 3)) * 100, quat_from_rpy(rng.normal(size=(n, 3)))
    )
    write_tum(tmp_path / "big.tum", s)
    import uwval.io.tum as tum

    reference = np.loadtxt(tmp_path / "big.tum")
    table = tum.parse_tum_file(tmp_path / "big.tum")
    assert table.shape == (n, 8)
    assert np.array_equal(table.view(np.int64), reference.view(np.int64))


def test_crlf_and_tabs_are_read(tmp_path: Path) -> None:
    f = tmp_path / "w.tum"
    f.write_bytes(b"1.5\t1 2 3 0 0 0 1\r\n2.5 4\t5 6 0 0 1 0\r\n")
    s = read_tum(f)
    assert s.t.tolist() == [1_500_000_000, 2_500_000_000]
    np.testing.assert_array_equal(s.position, [[1, 2, 3], [4, 5, 6]])


@pytest.mark.parametrize("stamp", ["nan", "inf", "1e10"])
def test_bad_stamps_are_errors_naming_the_pose_line(tmp_path: Path, stamp: str) -> None:
    f = tmp_path / "s.tum"
    f.write_text(f"# h\n1 0 0 0 0 0 0 1\n{stamp} 0 0 0 0 0 0 1\n")
    with pytest.raises(LogReadError, match=r"s.tum: pose line 2: timestamp"):
        read_tum(f)


# ---- two files at once: the forked reader gives what reading one after the other gives -----


def _pair(tmp_path: Path, n: int = 3000) -> tuple[Path, Path]:
    rng = np.random.default_rng(7)
    t = 1_700_000_000_000_000_000 + np.arange(n, dtype=np.int64) * 10**7
    a = PoseStream.from_arrays(t, rng.normal(size=(n, 3)), quat_from_rpy(rng.normal(size=(n, 3))))
    b = a.with_(t=t + 3_000_000, position=a.position + 0.01)
    write_tum(tmp_path / "a.tum", a)
    write_tum(tmp_path / "b.tum", b)
    return tmp_path / "a.tum", tmp_path / "b.tum"


def test_parallel_pair_equals_sequential_reads(tmp_path: Path) -> None:
    from uwval.io.tum import read_tum_pair

    a, b = _pair(tmp_path)
    pa, pb = read_tum_pair(a, b, frame_b="ned", topic_a="ref", parallel=True)
    sa, sb = read_tum(a, topic="ref"), read_tum(b, frame="ned")
    for got, want in ((pa, sa), (pb, sb)):
        np.testing.assert_array_equal(got.t, want.t)
        assert got.position.tobytes() == want.position.tobytes()
        assert got.orientation.tobytes() == want.orientation.tobytes()
        assert (got.frame, got.topic, got.source) == (want.frame, want.topic, want.source)


def test_parallel_pair_repairs_like_read_tum(tmp_path: Path) -> None:
    from uwval.io.tum import read_tum_pair

    a, b = _pair(tmp_path, 50)
    b.write_text("3 0 0 0 0 0 0 1\n1 0 0 0 0 0 0 1\n2 0 0 0 0 0 0 1\n")
    _, pb = read_tum_pair(a, b, parallel=True)
    assert pb.t.tolist() == [1_000_000_000, 2_000_000_000, 3_000_000_000]
    assert pb.repairs["sorted"] == 1


def test_parallel_pair_first_file_checks_win_over_second_file_errors(tmp_path: Path) -> None:
    # read one after the other, the first file's stream checks (here a quaternion of norm
    # 0.001) run before the second file is even opened: the parallel reader says the same
    from uwval.io.tum import read_tum_pair

    a, b = _pair(tmp_path, 50)
    a.write_text("1 0 0 0 0 0 0 1\n2 0 0 0 0 0 0 1e-3\n")
    b.write_text("1 2 3\n")  # malformed
    for second in (b, tmp_path / "missing.tum"):
        with pytest.raises(PoseStreamError, match=r"a\.tum.*norm 0\.001") as seq:
            read_tum(a), read_tum(second)
        with pytest.raises(PoseStreamError, match=r"a\.tum.*norm 0\.001") as par:
            read_tum_pair(a, second, parallel=True)
        assert str(par.value) == str(seq.value)


def _children() -> set[int]:
    """Live child processes of this one (Linux), to check the forked parser is reaped."""
    import os

    path = Path(f"/proc/{os.getpid()}/task/{os.getpid()}/children")
    return {int(x) for x in path.read_text().split()} if path.exists() else set()


def test_parallel_pair_errors_name_the_file_and_reap_the_child(tmp_path: Path) -> None:
    from uwval.io.tum import read_tum_pair

    a, b = _pair(tmp_path, 50)
    before = _children()
    b.write_text("1.0 0 0 0 0 0 0 1\n2.0 0 0 x 0 0 0 1\n")
    with pytest.raises(LogReadError, match=r"b.tum: line 2"):
        read_tum_pair(a, b, parallel=True)
    a.write_text("1.0 0 0 0 0 0 1\n")  # both bad: the first file's error, as sequential reads
    with pytest.raises(LogReadError, match=r"a.tum: line 1"):
        read_tum_pair(a, b, parallel=True)
    _pair(tmp_path, 50)
    with pytest.raises(LogReadError, match=r"missing\.tum: no such file"):
        read_tum_pair(a, tmp_path / "missing.tum", parallel=True)
    assert _children() == before


def test_compare_of_large_tum_pair_is_parallel_and_unchanged(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # compare_logs reads two TUM files through read_tum_pair: the JSON is the same whether the
    # second file is parsed concurrently (thread or forked child) or not
    import os

    import uwval.io.tum as tum
    from uwval.comparison.logs import compare_logs

    a, b = _pair(tmp_path)
    forks: list[int] = []
    real_fork = os.fork

    def counting_fork() -> int:
        pid = real_fork()
        if pid:
            forks.append(pid)
        return pid

    threads: list[str] = []
    real_pair = tum._threaded_pair

    def counting_pair(pa: Path, pb: Path) -> object:
        threads.append(str(pb))
        return real_pair(pa, pb)

    monkeypatch.setattr(tum, "PARALLEL_MIN_BYTES", 0)
    monkeypatch.setattr(tum.os, "fork", counting_fork)
    monkeypatch.setattr(tum, "_threaded_pair", counting_pair)
    forked = compare_logs(a, b, sync="nearest").to_json()
    # the C parser releases the GIL: the second file goes to a thread, else to a child
    assert (len(threads), len(forks)) == ((1, 0) if tum.USE_ACCELERATOR else (0, 1))
    monkeypatch.setattr(tum, "PARALLEL_MIN_BYTES", 1 << 40)
    sequential = compare_logs(a, b, sync="nearest").to_json()
    assert len(forks) + len(threads) == 1
    assert forked == sequential
    assert forked["counts"]["matched"] == 3000


def test_pair_is_read_in_this_process_when_other_threads_run(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # forking a multi-threaded process can deadlock the child: read sequentially instead
    import threading

    import uwval.io.tum as tum

    a, b = _pair(tmp_path, 50)
    monkeypatch.setattr(tum, "USE_ACCELERATOR", False)  # the path that would fork
    monkeypatch.setattr(tum, "PARALLEL_MIN_BYTES", 0)
    forks: list[int] = []

    def no_fork() -> int:
        forks.append(1)
        raise AssertionError("forked")

    stop = threading.Event()
    worker = threading.Thread(target=stop.wait)
    worker.start()
    try:
        monkeypatch.setattr(tum.os, "fork", no_fork)
        ra, rb = tum.read_tum_pair(a, b)
    finally:
        stop.set()
        worker.join()
    assert not forks
    assert len(ra) == len(rb) == 50


@pytest.mark.parametrize("accelerated", [True, False])
def test_a_carriage_return_inside_a_line_is_refused_not_read_as_space(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, accelerated: bool
) -> None:
    """Found by the fuzz harness: '-' flipped to CR turned -0.007853 into 0.007853 silently
    (both parsers took CR as blank space; loadtxt and evo see a line break). CRLF files stay
    fine."""
    import uwval.io.tum as tum

    if accelerated and tum._tumparse is None:
        pytest.skip("C accelerator not built")
    monkeypatch.setattr(tum, "USE_ACCELERATOR", accelerated)
    good = "1.0 0.1 -0.2 0.3 0 0 0 1\n2.0 0.1 -0.007853 0.3 0 0 0 1\n"
    p = tmp_path / "crlf.txt"
    p.write_bytes(good.replace("\n", "\r\n").encode())
    assert read_tum(p).position[1, 1] == -0.007853
    p = tmp_path / "damaged.txt"
    p.write_bytes(good.replace("-0.007853", "\r0.007853").encode())
    with pytest.raises(LogReadError, match=r"line 2 \(byte \d+\): a carriage return inside"):
        read_tum(p)
