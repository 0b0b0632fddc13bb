"""What the tests of the early reads (test_early_read.py: sqlite3 page scans) share:
reading a log, comparing streams, recording whether a read took the early result, and a
whole compare in a fresh process with the early start on or off."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

G, U = "/gazebo/model_rov_pose", "/unity/model_rov_pose"


def read(path: Path, topics: list[str]) -> dict[str, Any]:
    from uwval.io import read_streams

    return read_streams(path, topics)


def same_streams(a: dict[str, Any], b: dict[str, Any]) -> None:
    import numpy as np

    assert list(a) == list(b)
    for k in a:
        for f in ("t", "position", "orientation"):
            np.testing.assert_array_equal(getattr(a[k], f), getattr(b[k], f))
        np.testing.assert_array_equal(a[k].applied_stamp, b[k].applied_stamp)
        assert a[k].warnings == b[k].warnings


def spy_taken(monkeypatch: pytest.MonkeyPatch, module: Any) -> list[bool]:
    """Record, per read, whether it took the early result of ``module`` (its
    ``take_started``)."""
    got: list[bool] = []
    real = module.take_started

    def spy(*args: Any) -> Any:
        r = real(*args)
        got.append(r is not None)
        return r

    monkeypatch.setattr(module, "take_started", spy)
    return got


def write_pair(tmp_path: Path, fmt: str = "rosbag2", name: str = "bag") -> Path:
    """The Gazebo vehicle and its Unity view, 30 s at 100 Hz, written by uwval's writer as
    ``fmt`` (a rosbag2 storage, or any format open_writer takes) to ``tmp_path / name``."""
    from uwval.comparison.synthetic import unity_view, vehicle_motion
    from uwval.io.writers import open_writer, write_stream

    vehicle = vehicle_motion(3000, 100.0)
    unity = unity_view(vehicle)
    out = tmp_path / name
    with open_writer(out, fmt) as w:
        write_stream(w, vehicle.topic, vehicle, "enu")
        write_stream(w, unity.topic, unity, unity.frame)
    return out


def taken_only_when_own(
    monkeypatch: pytest.MonkeyPatch,
    module: Any,
    log: Path,
    touched: Path,
    case: str,
    read_topics: list[str],
    taken_expected: bool,
) -> None:
    """Start ``module``'s early read of ``log`` for G and U, change ``touched`` (its mtime)
    when ``case`` is "file touched", read ``read_topics``: the streams equal a plain read's,
    and the early result was taken exactly when ``taken_expected``; none is left behind."""
    from uwval.io import early

    plain = read(log, read_topics)
    taken = spy_taken(monkeypatch, module)
    early.start(log, [G, U])
    assert len(module._started) == 1
    if case == "file touched":
        st = touched.stat()
        os.utime(touched, ns=(st.st_atime_ns, st.st_mtime_ns + 1_000_000_000))
    same_streams(read(log, read_topics), plain)  # the same streams either way
    assert taken == [taken_expected] and not module._started


def compare_in_fresh_process(log: Path, module: str, tmp_path: Path) -> None:
    """``uwval compare LOG`` through the command line in a fresh process, with the early
    start on and off: on, the read takes ``module``'s early result; the JSON is the same."""
    code = (
        "import sys, json, importlib\n"
        "import uwval.cpus\n"
        "uwval.cpus.second_cpu_free = lambda: True\n"
        "import uwval.io.early as e\n"
        f"m = importlib.import_module({module!r})\n"
        "if sys.argv[1] == 'off':\n"
        "    e.start = lambda *a: None\n"
        "real = m.take_started\n"
        "seen = []\n"
        "def spy(*a):\n"
        "    got = real(*a)\n"
        "    seen.append(got is not None)\n"
        "    return got\n"
        "m.take_started = spy\n"
        "from uwval.cli import main\n"
        f"main(['compare', {str(log)!r}, '--gazebo-topic', {G!r}, '--unity-topic', {U!r},"
        " '--output', sys.argv[2]])\n"
        "print(seen)\n"
    )
    outs = {}
    for mode in ("on", "off"):
        out = tmp_path / f"{mode}.json"
        res = subprocess.run(
            [sys.executable, "-c", code, mode, str(out)],
            capture_output=True,
            text=True,
            check=True,
        )
        outs[mode] = json.loads(out.read_text())
        assert res.stdout.strip().splitlines()[-1] == ("[True]" if mode == "on" else "[False]")
    assert outs["on"] == outs["off"]
