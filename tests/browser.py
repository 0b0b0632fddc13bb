"""Headless Chromium screenshots and pixel ink of rendered reports."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import numpy as np

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")


def _chromium(page: Path, tmp_path: Path) -> tuple[Path, str]:
    """Load ``page`` in real headless Chromium; return (screenshot, its log on stderr)."""
    assert CHROMIUM is not None
    shot = tmp_path / "shot.png"
    res = subprocess.run(
        [
            CHROMIUM,
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--disable-quic",
            "--no-first-run",
            "--disable-background-networking",
            "--disable-component-update",
            "--disable-sync",
            f"--user-data-dir={tmp_path / 'profile'}",
            "--enable-logging=stderr",
            "--v=0",
            "--hide-scrollbars",
            "--window-size=1280,1600",
            f"--screenshot={shot}",
            page.as_uri(),
        ],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert res.returncode == 0, res.stderr[-2000:]
    return shot, res.stderr


def _console_errors(log: str) -> list[str]:
    # Chromium writes page console messages as "...:CONSOLE(line)] "message", source: ..."
    return [line for line in log.splitlines() if ":CONSOLE" in line]


def _ink(png: Path) -> tuple[float, float]:
    """(share of non-white pixels, grey-level std) of an image."""
    from PIL import Image

    a = np.asarray(Image.open(png).convert("L"), dtype=np.float64)
    return float((a < 245).mean()), float(a.std())
