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
