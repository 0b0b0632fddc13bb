"""TUM text reader/writer: exact stamps, repairs, and errors that name the line."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from uwval.errors import LogReadError, PoseStreamError
from uwval.io.tum import ns_from_seconds, read_tum, seconds_from_ns, write_tum
from uwval.posestream import PoseStream
from uwval.rotations import quat_from_rpy


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


def test_large_file_is_parsed_in_chunks(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import uwval.io.tum as tum

    monkeypatch.setattr(tum, "_CHUNK", 64)  # force many chunks and boundary cases
    rng = np.random.default_rng(2)
    n = 300
    s = PoseStream.from_arrays(np.arange(n, dtype=np.int64) * 10_000_000 + 5,
                               rng.normal(size=(n, 3)), quat_from_rpy(rng.normal(size=(n, 3))))
    write_tum(tmp_path / "c.tum", s)
    back = read_tum(tmp_path / "c.tum")
    np.testing.assert_array_equal(back.t, s.t)
    np.testing.assert_allclose(back.position, s.position, atol=1e-9)
    (tmp_path / "c.tum").write_text((tmp_path / "c.tum").read_text() + "1e99 1 2\n")
    with pytest.raises(LogReadError, match=f"line {n + 2}"):
        read_tum(tmp_path / "c.tum")
