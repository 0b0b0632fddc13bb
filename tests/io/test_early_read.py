"""uwval.io.early: a sqlite3 bag's page scan begun before the compare's imports is taken by
the read only when it is exactly the read's own scan; the results are the same either way;
anything it cannot decide cheaply starts nothing."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

from accelerators import require_module
from early_helpers import (
    G,
    U,
    compare_in_fresh_process,
    taken_only_when_own,
    write_pair,
)
from uwval.io import db3_pages, early

require_module(db3_pages._db3pages, "uwval.io._db3pages")


@pytest.fixture(autouse=True)
def _second_cpu_and_no_leftovers(monkeypatch: pytest.MonkeyPatch) -> Any:
    import uwval.cpus

    monkeypatch.setattr(uwval.cpus, "second_cpu_free", lambda: True)
    monkeypatch.setattr(db3_pages, "USE_ACCELERATOR", True)
    db3_pages._started.clear()
    yield
    for scan in db3_pages._started.values():
        scan.thread.join()
    db3_pages._started.clear()


@pytest.mark.parametrize(
    ("case", "read_topics", "taken_expected"),
    [
        ("the same scan", [G, U], True),
        ("other topics", [G], False),  # the scan began for G and U, the read asks for G
        ("file touched", [G, U], False),  # the file changed after the scan began
    ],
)
def test_the_read_takes_the_early_scan_only_when_it_is_its_own(
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    case: str,
    read_topics: list[str],
    taken_expected: bool,
) -> None:
    bag = write_pair(tmp_path)
    db3 = next(bag.glob("*.db3"))
    taken_only_when_own(monkeypatch, db3_pages, bag, db3, case, read_topics, taken_expected)


@pytest.mark.parametrize("case", ["mcap-file", "rosbag2-mcap", "no-metadata", "compressed", "wal"])
def test_nothing_is_started_where_it_cannot_be_decided_cheaply(tmp_path: Path, case: str) -> None:
    if case == "mcap-file":  # nothing is started early for MCAP files
        from uwval.comparison.synthetic import unity_view, vehicle_motion, write_pair_log

        v = vehicle_motion(200)
        target = write_pair_log(tmp_path / "a.mcap", v, unity_view(v))
    elif case == "rosbag2-mcap":
        target = write_pair(tmp_path, "rosbag2-mcap")
    else:
        target = write_pair(tmp_path)
        meta = target / "metadata.yaml"
        if case == "no-metadata":
            meta.unlink()
        elif case == "compressed":
            meta.write_text(
                meta.read_text().replace("compression_mode: ''", "compression_mode: FILE")
            )
            assert "FILE" in meta.read_text()
        else:
            db3 = next(target.glob("*.db3"))
            db3.with_name(db3.name + "-wal").write_bytes(b"x" * 100)
    early.start(target, [G, U])
    assert not db3_pages._started


def test_a_damaged_bag_starts_nothing_and_raises_nothing(tmp_path: Path) -> None:
    bag = write_pair(tmp_path)
    db3 = next(bag.glob("*.db3"))
    db3.write_bytes(b"not a database" * 100)
    early.start(bag, [G, U])  # sqlite3 fails inside: swallowed, nothing pending
    assert not db3_pages._started


def test_a_compare_through_the_command_line_takes_the_early_scan(tmp_path: Path) -> None:
    """The whole command, in a fresh process: the early scan is taken, and the JSON equals
    the one of a process where early reads are disabled."""
    bag = write_pair(tmp_path)
    compare_in_fresh_process(bag, "uwval.io.db3_pages", tmp_path)


def test_the_early_path_loads_no_numpy() -> None:
    """The early scan overlaps numpy's import only if everything it needs loads without it."""
    code = (
        "import sys\n"
        "import uwval.cli.compare_run, uwval.io.early, uwval.io.db3_pages, uwval.topics\n"
        "print('numpy' in sys.modules)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"
