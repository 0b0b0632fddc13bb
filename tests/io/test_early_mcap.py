"""uwval.io.early for MCAP files: the C runs begun before the compare's imports
(:mod:`uwval.io.mcap_runs`) are taken by the read only when they are exactly the read's own
(same file unchanged, first chunk, summary, channel table); the streams are the same either
way; a log in any unusual form starts nothing, and nothing in the early path loads numpy."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

from early_helpers import (
    G,
    U,
    compare_in_fresh_process,
    read,
    same_streams,
    spy_taken,
    taken_only_when_own,
    write_pair,
)
from uwval.io import early, mcap_runs


@pytest.fixture(autouse=True)
def _ready(monkeypatch: pytest.MonkeyPatch) -> Any:
    if not mcap_runs.scan_ready():
        if os.environ.get("UWVAL_REQUIRE_ACCELERATOR"):
            pytest.fail("the C run reader is not available (UWVAL_REQUIRE_ACCELERATOR is set)")
        pytest.skip("no C run reader here (uwval.io._mcapwalk or libzstd.so.1 missing)")
    import uwval.cpus

    monkeypatch.setattr(uwval.cpus, "second_cpu_free", lambda: True)
    mcap_runs._started.clear()
    yield
    for run in mcap_runs._started.values():
        run.thread.join()
    mcap_runs._started.clear()


def _log(tmp_path: Path, *, metadata_first: bool = False, name: str = "log.mcap") -> Path:
    """A two-topic log (uwval's writer), chunked small: many runs."""
    from uwval.comparison.synthetic import unity_view, vehicle_motion, write_pair_log

    v = vehicle_motion(3000, 100.0)
    path = write_pair_log(tmp_path / name, v, unity_view(v))
    if metadata_first:  # a Metadata record between the Header and the first chunk
        import struct

        data = bytearray(path.read_bytes())
        (hl,) = struct.unpack_from("<Q", data, 9)
        meta = struct.pack("<I", 1) + b"m" + struct.pack("<I", 0)
        rec = bytes([0x0C]) + struct.pack("<Q", len(meta)) + meta
        # the summary's offsets move with it: only the data section's start is read here
        path.write_bytes(bytes(data[: 8 + 9 + hl]) + rec + bytes(data[8 + 9 + hl :]))
    return path


@pytest.mark.parametrize(
    ("case", "read_topics", "taken_expected"),
    [
        ("the same runs", [G, U], True),
        ("other topics", [G], False),  # the runs began for G and U, the read asks for G
        ("file touched", [G, U], False),  # the file changed after the runs began
    ],
)
def test_the_read_takes_the_early_runs_only_when_they_are_its_own(
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    case: str,
    read_topics: list[str],
    taken_expected: bool,
) -> None:
    log = _log(tmp_path)
    monkeypatch.setattr(mcap_runs, "EARLY_FILE_BYTES", 20_000)  # many runs
    taken_only_when_own(monkeypatch, mcap_runs, log, log, case, read_topics, taken_expected)


def test_a_rosbag2_bag_of_one_mcap_file_is_started_and_taken(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    bag = write_pair(tmp_path, "rosbag2-mcap")
    plain = read(bag, [G, U])
    taken = spy_taken(monkeypatch, mcap_runs)
    early.start(bag, [G, U])
    assert len(mcap_runs._started) == 1
    same_streams(read(bag, [G, U]), plain)
    assert taken == [True]


def test_early_runs_stopped_by_a_damaged_chunk_are_taken_and_the_read_goes_on(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from mcap.reader import make_reader

    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    import io_loggen

    # interleaved topics, small chunks (uwval's own writer makes few large ones)
    log = io_loggen.write_log(tmp_path / "log.mcap", "mcap", seconds=6.0, chunk_size=4096)
    with open(log, "rb") as fh:
        summary = make_reader(fh).get_summary()
    assert summary is not None and len(summary.chunk_indexes) > 4
    chunk = sorted(c.chunk_start_offset for c in summary.chunk_indexes)[2]
    data = bytearray(log.read_bytes())
    data[chunk + 9 + 60] ^= 0xFF  # inside its compressed records: it fails its check
    log.write_bytes(bytes(data))
    plain = read(log, [G, U])
    assert any(f"MCAP chunk at byte {chunk}" in w for w in plain[G].warnings)
    taken = spy_taken(monkeypatch, mcap_runs)
    early.start(log, [G, U])
    same_streams(read(log, [G, U]), plain)
    assert taken[0] is True  # the runs before the damaged chunk


@pytest.mark.parametrize("case", ["no-summary", "metadata-first", "not-mcap", "no-accelerator"])
def test_nothing_is_started_where_it_cannot_be_decided_cheaply(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, case: str
) -> None:
    log = _log(tmp_path, metadata_first=case == "metadata-first")
    if case == "no-summary":  # a recording cut short
        log.write_bytes(log.read_bytes()[: log.stat().st_size * 2 // 3])
    elif case == "not-mcap":
        log = log.rename(log.with_suffix(".bin"))
    elif case == "no-accelerator":
        monkeypatch.setenv("UWVAL_NO_ACCELERATOR", "1")
    early.start(log, [G, U])
    assert not mcap_runs._started


def test_a_damaged_summary_starts_nothing_and_raises_nothing(tmp_path: Path) -> None:
    log = _log(tmp_path)
    data = bytearray(log.read_bytes())
    data[-8 - 29 - 100] ^= 0x55  # inside the summary: its CRC no longer matches
    log.write_bytes(bytes(data))
    early.start(log, [G, U])
    assert not mcap_runs._started


def test_a_compare_through_the_command_line_takes_the_early_runs(tmp_path: Path) -> None:
    """The whole command, in a fresh process: the early runs are taken, and the JSON equals
    the one of a process where early reads are disabled."""
    log = _log(tmp_path)
    compare_in_fresh_process(log, "uwval.io.mcap_runs", tmp_path)


def test_the_early_runs_load_no_numpy(tmp_path: Path) -> None:
    """The early runs overlap numpy's import only if everything they need loads without it."""
    log = _log(tmp_path)
    code = (
        "import sys\n"
        "import uwval.cpus\n"
        "uwval.cpus.second_cpu_free = lambda: True\n"
        "from uwval.io import early, mcap_runs\n"
        f"early.start({str(log)!r}, [{G!r}, {U!r}])\n"
        "(run,) = mcap_runs._started.values()\n"
        "run.thread.join()\n"
        "print(len(run.result), 'numpy' in sys.modules)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    n, numpy_loaded = out.stdout.split()
    assert int(n) >= 1 and numpy_loaded == "False"
