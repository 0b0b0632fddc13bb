"""Clock offset and latency, end to end: a Unity clock 3 s ahead and 50 ms of link latency."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest
from cli_runner import run_uwval as _uwval
from cli_runner import simulate_log


@pytest.fixture(scope="module")
def offset_log(tmp_path_factory: pytest.TempPathFactory) -> Path:
    log = tmp_path_factory.mktemp("off") / "off.mcap"
    return simulate_log(
        log,
        "--unity-clock-offset",
        "3",
        "--latency",
        "0.05",
        # the exact Unity side (simulate defaults to a real one: real-endpoint link, vsync
        # stalls, float32, 20 ppm drift): this checks the offset and latency arithmetic
        "--transport",
        "ideal",
        "--frame-model",
        "fixed",
        "--no-float32",
        "--unity-clock-drift",
        "0",
    )


def _json(log: Path, *args: str) -> dict[str, Any]:
    res = _uwval("compare", str(log), "--json", *args)
    assert res.returncode == 0, res.stderr
    out: dict[str, Any] = json.loads(res.stdout)
    return out


def test_known_offset_gives_absolute_latency(offset_log: Path) -> None:
    d = _json(offset_log, "--offset", "-3")
    lat = d["latency"]
    # 50 ms link latency + on average half a 60 Hz frame of waiting for the next render
    assert lat["mean_ms"] == pytest.approx(50.0 + 1000 / 120, abs=1.0)
    assert lat["min_ms"] >= 50.0 - 1e-6
    assert lat["max_ms"] <= 50.0 + 1000 / 60 + 1e-6
    assert "note" not in lat
    assert d["axes"]["x"]["pearson_r"] > 0.99


def test_auto_offset_recovers_clock_offset_plus_mean_delay(offset_log: Path) -> None:
    d = _json(offset_log, "--offset", "auto")
    est = d["offset"]["estimate"]
    # the motion shows Unity 3 s + ~58 ms behind: the estimate absorbs the delay, and says so
    assert est["offset_s"] == pytest.approx(-(3.0 + 0.05 + 1 / 120), abs=0.004)
    assert est["uncertainty_s"] < 0.01
    assert "absorbs the mean latency" in d["latency"]["note"]
    assert d["axes"]["x"]["mae"] < 0.005


def test_without_offset_the_streams_do_not_line_up(offset_log: Path) -> None:
    # 3 s of clock offset uncorrected: the comparison sees a 3 s shift of the motion
    d = _json(offset_log)
    assert d["axes"]["x"]["mae"] > 1.0
