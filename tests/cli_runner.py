"""One way for the tests to run the ``uwval`` command line as a user does: a fresh process."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from typing import Any


def run_uwval(
    *args: str | Path, timeout: float = 120, check: bool = False, cwd: Path | None = None
) -> subprocess.CompletedProcess[str]:
    """``python -m uwval ARGS`` with no stdin (as in CI); output captured as text."""
    return subprocess.run(
        [sys.executable, "-m", "uwval", *map(str, args)],
        capture_output=True,
        text=True,
        timeout=timeout,
        check=check,
        cwd=cwd,
        stdin=subprocess.DEVNULL,
    )


def compare_json(*args: str) -> dict[str, Any]:
    """``uwval compare ARGS --json``, checked to succeed, parsed."""
    res = run_uwval("compare", *args, "--json")
    assert res.returncode == 0, res.stderr
    out: dict[str, Any] = json.loads(res.stdout)
    return out


#: The end-to-end tests' run: surge, yaw torque and a cross current for 20 s.
STANDARD_RUN = (
    "--force",
    "10,0,0",
    "--torque",
    "0,0,1",
    "--current",
    "0,0.2,0",
    "--duration",
    "20",
)


def simulate_log(path: Path, *extra: str) -> Path:
    """``uwval simulate`` of the standard run (plus ``extra`` options) into ``path``, checked
    to succeed."""
    res = run_uwval("simulate", *STANDARD_RUN, *extra, "-o", path)
    assert res.returncode == 0, res.stderr
    return path
