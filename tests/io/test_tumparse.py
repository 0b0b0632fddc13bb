"""The C accelerator of the TUM reader: the same doubles as ``float()``, token for token."""

from __future__ import annotations

import io
import os
import threading
import time
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pytest
from accelerators import require_module
from hypothesis import given, settings
from hypothesis import strategies as st

import uwval.io.tum as tum

if TYPE_CHECKING:
    from typing_extensions import Buffer

require_module(tum._tumparse, "uwval.io._tumparse")

parse_block = tum._tumparse.parse_block


def _parse(text: bytes, final: bool = True, cap: int = 64) -> tuple[int, int, np.ndarray]:
    stamps = np.full(cap, np.nan)
    pose = np.full((cap, 7), np.nan)
    rows, used = parse_block(text, stamps, pose, final)
    return rows, used, np.column_stack([stamps, pose])[:rows]


def _same_doubles(got: np.ndarray, want: list[float]) -> bool:
    return got.view(np.int64).tolist() == np.array(want).view(np.int64).tolist()


# decimal tokens of every shape the fast path and its strtod fallback must get right
_digits = st.text("0123456789", min_size=1, max_size=25)
_token = st.one_of(
    st.floats(allow_nan=False, allow_infinity=False).map(repr),
    st.floats(allow_nan=False, allow_infinity=False).map("{:.17e}".format),
    st.floats(-1e7, 1e7, allow_nan=False).map("{:.9f}".format),
    st.floats(0, 4e9, allow_nan=False).map("{:.6f}".format),
    st.builds(
        lambda s, a, b, e: f"{s}{a}.{b}{e}",
        st.sampled_from(["", "-", "+"]),
        _digits,
        _digits,
        st.sampled_from(
            [
                "",
                "e5",
                "E-7",
                "e+22",
                "e-22",
                "e23",
                "e-330",
                "e308",
                "e-300",
                "E0",
                "e-5000",
                "e99999999",
            ]
        ),
    ),
    st.builds(lambda a: f".{a}", _digits),
    st.builds(lambda a: f"{a}.", _digits),
    st.sampled_from(
        [
            "0",
            "-0",
            "-0.0",
            "+0.000",
            "4.9e-324",
            "2.4703282292062327e-324",
            "1.7976931348623157e308",
            "1.7976931348623159e308",
            "9007199254740993",
            "9007199254740992",
            "9007199254740991",
            "0.1",
            "1e22",
            "1e23",
            "123456789012345678901234567890",
            "0.000000000000000000000000000001",
            "1700000000.123456789",
            "1305031102.175304",
        ]
    ),
)


@settings(max_examples=1500, deadline=None)
@given(st.lists(_token, min_size=8, max_size=8), st.sampled_from([" ", "\t", "  ", " \t\r"]))
def test_every_token_is_the_double_float_gives(tokens: list[str], sep: str) -> None:
    line = sep.join(tokens).encode()
    rows, used, table = _parse(line + b"\n")
    assert (rows, used) == (1, len(line) + 1)
    assert _same_doubles(table[0], [float(t) for t in tokens])


def test_lines_blank_lines_crlf_and_the_last_line() -> None:
    text = b"1 2 3 4 5 6 7 8\r\n\n   \n\t9 10 11 12 13 14 15 16  \n17 18 19 20 21 22 23 24"
    rows, used, table = _parse(text, final=False)
    assert (rows, used) == (2, text.index(b"17"))  # the unterminated line waits for more text
    assert table[:, 0].tolist() == [1.0, 9.0]
    rows, used, table = _parse(text, final=True)
    assert (rows, used) == (3, len(text))
    assert table[2].tolist() == list(range(17, 25))


def test_stops_when_the_outputs_are_full() -> None:
    text = b"".join(b"%d 0 0 0 0 0 0 1\n" % i for i in range(10))
    rows, used, table = _parse(text, cap=4)
    assert rows == 4
    assert used == text.index(b"4 0 0")
    assert table[:, 0].tolist() == [0, 1, 2, 3]


@pytest.mark.parametrize(
    "bad",
    [
        b"1 2 3 4 5 6 7",
        b"1 2 3 4 5 6 7 8 9",
        b"# comment",
        b"1 2 3 4 5 6 7 x",
        b"1,2,3,4,5,6,7,8",
        b"nan 1 2 3 4 5 6 7",
        b"1 2 3 4 5 6 7 1e",
        b"1 2 3 4 5 6 7 +",
        b"1 2 3 4 5 6 7 .",
        b"1 2 3 4 5 6 7 0x10",
        b"1 2 3 4 5 6 7 1_0",
        b"1 2 3 4 5 6 7 " + b"1" * 200,
        b"1 2 3 4 5 6 7 0." + b"0" * 5000 + b"1",
    ],
)
def test_anything_but_8_plain_decimals_is_refused_with_the_line_offset(bad: bytes) -> None:
    text = b"1 0 0 0 0 0 0 1\n" + bad + b"\n2 0 0 0 0 0 0 1\n"
    with pytest.raises(ValueError, match=r"^byte 16: not a line of 8 decimal numbers"):
        _parse(text)


def test_refused_tokens_are_still_read_by_the_thorough_path(tmp_path: Path) -> None:
    # over-long numbers are left to Python (the C counters stay far from overflow)
    f = tmp_path / "long.tum"
    long_zero = "0." + "0" * 5000 + "1"
    f.write_text(f"1 0 0 0 0 0 0 1\n2 {long_zero} 0 0 0 0 0 1\n")
    stream = tum.read_tum(f)
    assert stream.position[1, 0] == float(long_zero)


def test_outputs_must_be_writable_float_buffers() -> None:
    with pytest.raises(BufferError):
        parse_block(b"1 2 3 4 5 6 7 8\n", b"\0" * 64, np.zeros(7), True)
    for wrong in (bytearray(16), np.zeros(2, dtype=np.int64), np.zeros(2, dtype=np.float32)):
        with pytest.raises(TypeError, match="float64"):
            parse_block(b"1 2 3 4 5 6 7 8\n", wrong, np.zeros(7), True)
    with pytest.raises(ValueError):  # not contiguous
        parse_block(b"1 2 3 4 5 6 7 8\n", np.zeros(4)[::2], np.zeros(7), True)


def test_releases_the_gil_while_parsing() -> None:
    # a thread that counts while a large block is parsed gets to run during the parse
    text = b"1700000000.010000000 -2.274614941 1.984563543 -4.796312114 0.1 0.2 0.3 0.9\n"
    text *= 200_000
    stamps, pose = np.empty(200_000), np.empty((200_000, 7))
    ticks = []
    done = threading.Event()

    def tick() -> None:
        while not done.is_set():
            ticks.append(time.perf_counter())
            time.sleep(0.0005)

    worker = threading.Thread(target=tick)
    worker.start()
    time.sleep(0.01)
    start = time.perf_counter()
    rows, _ = parse_block(text, stamps, pose, True)
    end = time.perf_counter()
    done.set()
    worker.join()
    assert rows == 200_000
    assert any(start < t < end for t in ticks), "no tick ran during the parse"


class _RecordingReader(io.BytesIO):
    """A binary file that records how many bytes each ``readinto`` asked for."""

    def __init__(self, data: bytes) -> None:
        super().__init__(data)
        self.asked: list[int] = []

    def readinto(self, buffer: Buffer) -> int:  # type: ignore[override]
        self.asked.append(memoryview(buffer).nbytes)
        return super().readinto(buffer)


def test_growing_the_arrays_does_not_grow_the_text_buffer(tmp_path: Path) -> None:
    # rows estimated far too low, and lines that end exactly at the buffer's edge: the arrays
    # grow many times; the text buffer must stay one block (it once doubled at each growth)
    line = b"1 0 0 0 0 0 0 1\n"
    per_block = tum._CHUNK // len(line)  # the arrays fill up exactly at a block's end
    n = 16 * per_block
    reader = _RecordingReader(line * n)
    t, pose = tum._fill_accelerated(
        reader,
        b"",
        tmp_path / "x.tum",  # type: ignore[arg-type]
        np.empty(per_block, np.int64),
        np.empty((per_block, 7)),
        False,
    )
    assert t.shape == (n,)
    assert np.array_equal(pose, np.tile([0.0, 0, 0, 0, 0, 0, 1], (n, 1)))
    assert max(reader.asked) <= tum._CHUNK


def test_the_environment_can_switch_the_accelerator_off() -> None:
    import subprocess
    import sys

    probe = "import uwval.io.tum as t; print(t.USE_ACCELERATOR)"
    for value, expected in (("1", "False"), (None, "True")):
        env = {k: v for k, v in os.environ.items() if k != "UWVAL_NO_ACCELERATOR"}
        if value is not None:
            env["UWVAL_NO_ACCELERATOR"] = value
        out = subprocess.run(
            [sys.executable, "-c", probe],
            capture_output=True,
            text=True,
            env=env,
            timeout=60,
            check=True,
        )
        assert out.stdout.strip() == expected
