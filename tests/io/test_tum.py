"""TUM text reader/writer: exact stamps, repairs, one rule for separators, and errors that name
the file, the line and what is wrong."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from cli_runner import run_uwval
from hypothesis import given, settings
from hypothesis import strategies as st

import uwval.io.tum as tum_module
from uwval.errors import LogReadError
from uwval.io.tum import ns_from_seconds, read_tum, read_tum_pair, seconds_from_ns, write_tum
from uwval.posestream import PoseStream
from uwval.rotations import quat_from_rpy


def test_parses_comments_and_values(tmp_path: Path) -> None:
    f = tmp_path / "a.tum"
    f.write_text(
        "# header\n1.5 1 2 3 0 0 0 1\n  # indented comment\n\t# tab\n"
        "2.25 4 5 6 0 0 1 0  # trailing comment\n   \n\n"
    )
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


@pytest.mark.parametrize("value", ["nan", "inf", "-inf", "1e999", "NA", "1_0", "0x10", "1,5"])
def test_a_value_that_is_no_finite_number_is_refused_naming_the_line(
    tmp_path: Path, value: str
) -> None:
    f = tmp_path / "n.tum"
    f.write_text(f"# h\n1 0 0 0 0 0 0 1\n2 {value} 0 0 0 0 0 1\n")
    with pytest.raises(LogReadError, match=r"n\.tum: line 3 \(byte offset 20\): tx "):
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


def test_badly_non_unit_quaternion_is_refused_naming_the_line(tmp_path: Path) -> None:
    f = tmp_path / "s.tum"
    f.write_text("1 0 0 0 0 0 0 1\n# gap\n\n2 0 0 0 0 0 0 0.9\n")
    with pytest.raises(LogReadError, match=r"s\.tum: line 4 \(byte offset 23\): quaternion .*0\.9"):
        read_tum(f)


def test_an_error_far_down_a_large_file_names_its_line(tmp_path: Path) -> None:
    rng = np.random.default_rng(2)
    n = 3000
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
    with pytest.raises(LogReadError, match=f"line {n + 2} .*got 3 fields"):
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
@given(_tum_text())
def test_parser_equals_float_bit_for_bit(
    tmp_path_factory: pytest.TempPathFactory, case: tuple[str, list[list[str]]]
) -> None:
    text, tokens = case
    f = tmp_path_factory.mktemp("tum") / "h.tum"
    f.write_bytes(text.encode())
    expected = np.array([[float(tok) for tok in row] for row in tokens])
    stamps, position, quat = tum_module._parse(f.read_bytes(), f)
    assert stamps.view(np.int64).tolist() == expected[:, 0].view(np.int64).tolist()
    got = np.column_stack([position, quat])
    assert got.view(np.int64).tolist() == expected[:, 1:].view(np.int64).tolist()


def test_parser_matches_numpy_loadtxt_on_a_large_clean_file(tmp_path: Path) -> None:
    # many blocks of the fast path (no comments), compared with np.loadtxt on the whole text
    rng = np.random.default_rng(5)
    n = 20_000
    t = 1_700_000_000_000_000_000 + np.arange(n, dtype=np.int64) * 10**7
    s = PoseStream.from_arrays(
        t, rng.normal(size=(n, 3)) * 100, quat_from_rpy(rng.normal(size=(n, 3)))
    )
    write_tum(tmp_path / "big.tum", s)
    reference = np.loadtxt(tmp_path / "big.tum")
    stamps, position, quat = tum_module._parse((tmp_path / "big.tum").read_bytes(), tmp_path)
    table = np.column_stack([stamps, position, quat])
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
    with pytest.raises(LogReadError, match=r"s.tum: line 3 \(byte offset 20\): timestamp"):
        read_tum(f)


# ---- two files: read one after the other ----------------------------------------------------


def _pair(tmp_path: Path, n: int = 3000) -> tuple[Path, Path]:
    rng = np.random.default_rng(7)
    t = 1_700_000_000_000_000_000 + np.arange(n, dtype=np.int64) * 10**7
    a = PoseStream.from_arrays(t, rng.normal(size=(n, 3)), quat_from_rpy(rng.normal(size=(n, 3))))
    b = a.with_(t=t + 3_000_000, position=a.position + 0.01)
    write_tum(tmp_path / "a.tum", a)
    write_tum(tmp_path / "b.tum", b)
    return tmp_path / "a.tum", tmp_path / "b.tum"


def test_pair_equals_two_reads_and_the_first_files_error_wins(tmp_path: Path) -> None:
    a, b = _pair(tmp_path)
    pa, pb = read_tum_pair(a, b, frame_b="ned", topic_a="ref")
    sa, sb = read_tum(a, topic="ref"), read_tum(b, frame="ned")
    for got, want in ((pa, sa), (pb, sb)):
        np.testing.assert_array_equal(got.t, want.t)
        assert got.position.tobytes() == want.position.tobytes()
        assert got.orientation.tobytes() == want.orientation.tobytes()
        assert (got.frame, got.topic, got.source) == (want.frame, want.topic, want.source)
    a.write_text("1 0 0 0 0 0 0 1\n2 0 0 0 0 0 0 1e-3\n")
    b.write_text("1 2 3\n")
    with pytest.raises(LogReadError, match=r"a\.tum: line 2 .*norm 0\.001"):
        read_tum_pair(a, b)
    with pytest.raises(LogReadError, match=r"missing\.tum: no such file"):
        read_tum_pair(b.with_name("missing.tum"), b)


def test_a_carriage_return_inside_a_line_is_refused_not_read_as_space(tmp_path: Path) -> None:
    """Found by the fuzz harness: '-' flipped to CR turned -0.007853 into 0.007853 silently
    (both parsers took CR as blank space; loadtxt and evo see a line break). CRLF files stay
    fine."""
    good = "1.0 0.1 -0.2 0.3 0 0 0 1\n2.0 0.1 -0.007853 0.3 0 0 0 1\n"
    p = tmp_path / "crlf.txt"
    p.write_bytes(good.replace("\n", "\r\n").encode())
    assert read_tum(p).position[1, 1] == -0.007853
    p = tmp_path / "damaged.txt"
    p.write_bytes(good.replace("-0.007853", "\r0.007853").encode())
    with pytest.raises(LogReadError, match=r"line 2 \(byte offset 33\): a carriage return inside"):
        read_tum(p)


# ---- one rule for what separates fields, whichever way a file is laid out ----------------------

_STRAY = [
    (b"\xa0", "byte 0xA0 (no-break space)"),
    (b"\x1c", "byte 0x1C (file separator)"),
    (b"\x0b", "byte 0x0B (vertical tab)"),
    (b"\x0c", "byte 0x0C"),
    (b"\xc2\xa0", "byte 0xC2"),  # UTF-8's no-break space
    (b"\x00", "byte 0x00"),
]


@pytest.mark.parametrize(("layout"), ["plain", "comments", "crlf", "long"])
@pytest.mark.parametrize(("sep", "named"), _STRAY)
def test_a_foreign_separator_is_refused_naming_line_and_byte(
    tmp_path: Path, sep: bytes, named: str, layout: str
) -> None:
    """0xA0 or 0x1C between two fields: refused, naming the line, the byte offset and the
    byte, however the rest of the file looks (with or without comments, CRLF, long files).
    Before, numpy's path read ``2.0<0xA0>1`` as two fields of a comment-free file and refused
    the same line once the file had a comment further down."""
    n = 5000 if layout == "long" else 5
    lines = [b"%d.0 1 2 3 0 0 0 1" % i for i in range(n)]
    k = n - 2
    lines[k] = lines[k].replace(b".0 1", b".0" + sep + b"1", 1)
    head = [b"# timestamp tx ty tz qx qy qz qw \xc3\xa9 \xa0"] if layout == "comments" else []
    tail = [b"  # the end \x1c"] if layout == "comments" else []
    eol = b"\r\n" if layout == "crlf" else b"\n"
    body = eol.join(head + lines + tail) + eol
    f = tmp_path / "sep.tum"
    f.write_bytes(body)
    offset = body.index(sep, body.index(lines[k].split(sep)[0]))
    line = len(head) + k + 1
    want = rf"sep\.tum: line {line} \(byte offset {offset}\): {re.escape(named)}: refused"
    with pytest.raises(LogReadError, match=want):
        read_tum(f)


def test_a_foreign_separator_fails_the_command_in_one_line(tmp_path: Path) -> None:
    a, b = _pair(tmp_path, 20)
    text = b.read_bytes()
    cut = text.index(b" ", text.index(b"\n") + 1)  # first space of the first pose line
    b.write_bytes(text[:cut] + b"\xa0" + text[cut + 1 :])
    proc = run_uwval("compare", str(a), str(b), "--sync", "nearest")
    assert proc.returncode == 2
    err = proc.stderr.strip()
    assert "\n" not in err and "Traceback" not in err
    assert f"b.tum: line 2 (byte offset {cut}): byte 0xA0 (no-break space): refused" in err


def test_foreign_bytes_inside_comments_are_fine_and_a_bom_is_skipped(tmp_path: Path) -> None:
    f = tmp_path / "c.tum"
    f.write_bytes(
        b"\xef\xbb\xbf# r\xc3\xa9f\xa0\x1c\n1 0 0 0 0 0 0 1 # \xa0 ok\n  #\x0b\n2 0 0 0 0 0 0 1\n"
    )
    assert read_tum(f).t.tolist() == [1_000_000_000, 2_000_000_000]


def test_comments_may_hold_any_bytes(tmp_path: Path) -> None:
    # docs/formats.md: UTF-8 text or stray bytes inside a comment (whole, indented or
    # trailing) are not read
    f = tmp_path / "u8.tum"
    f.write_bytes(
        b"# Z\xc3\xbcrich \xff\xfe\n1.5 1 2 3 0 0 0 1  # trailing \xe2\x82\xac\n"
        b"  # indented \xa0\n2.5 4 5 6 0 0 1 0\n"
    )
    s = read_tum(f)
    assert s.t.tolist() == [1_500_000_000, 2_500_000_000]
    np.testing.assert_array_equal(s.position, [[1, 2, 3], [4, 5, 6]])
