"""What the tests of the early reads (test_early_read.py: sqlite3 page scans, test_early_mcap.py:
MCAP runs) share: reading a log, comparing streams, recording whether a read took the early
result, and a whole compare in a fresh process with the early start on or off."""

from __future__ import annotations

import json
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
