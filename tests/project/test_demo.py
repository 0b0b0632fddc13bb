"""The README's first quick-start command: ``uwval demo`` end to end, as a user runs it."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pandas as pd


def test_demo_end_to_end(tmp_path: Path) -> None:
    out = tmp_path / "uwval-demo"
    res = subprocess.run(
        [sys.executable, "-m", "uwval", "demo", "-o", str(out)],
        capture_output=True,
        text=True,
        timeout=300,
        stdin=subprocess.DEVNULL,
    )
    assert res.returncode == 0, res.stdout[-3000:] + res.stderr[-3000:]
    assert "uwval check: PASS" in res.stdout
    manifest = json.loads((out / "manifest.json").read_text())
    assert len(manifest["runs"]) == 54  # 3 x 3 x 3 levels x 2 seeds
    assert not manifest["failed"]
    for run in manifest["runs"]:
        assert (out / run["log"]).stat().st_size > 0
    df = pd.read_csv(out / "results" / "results.csv")
    assert set(df["run"]) == {r["name"] for r in manifest["runs"]}
    # the paper's three metrics are present for every run, topic and axis
    six = df[df["axis"].isin(["x", "y", "z", "roll", "pitch", "yaw"])]
    for metric in ("mae", "max", "pearson_r"):
        assert len(six[six["metric"] == metric]) == 54 * 2 * 6
    # every vehicle axis has a defined Pearson r (all six DOF are excited); the following
    # camera stays level, so its roll and pitch are constant and their r is undefined
    r = six[six["metric"] == "pearson_r"]
    assert r[r["topic"] == "model_rov_pose"]["value"].notna().all()
    cam = r[r["topic"] == "gui_camera_pose"]
    assert cam[cam["axis"].isin(["x", "y", "z", "yaw"])]["value"].notna().all()
    html = (out / "report.html").read_text()
    assert "PASS" in html
    assert "<img" in html
    assert (out / "report.pdf").read_bytes()[:5] == b"%PDF-"
    # issue 31: the answer, not only the numbers. analysis.json holds the factorial analysis
    # with partial eta^2 for force, torque and current per axis of the vehicle ...
    analysis = json.loads((out / "results" / "analysis.json").read_text())
    assert analysis["n_runs"] == 54
    assert set(analysis["factors"]) == {"force", "torque", "current"}
    for axis in ("x", "y", "z", "roll", "pitch", "yaw"):
        terms = {t["term"]: t for t in analysis["topics"]["model_rov_pose"][axis]["mae"]["terms"]}
        for factor in ("force", "torque", "current"):
            assert 0.0 <= terms[factor]["partial_eta_sq"] <= 1.0, (axis, factor)
    assert "late" in analysis["answer"]
    # ... and its two seeds are real replicates: each cell's runs differ in x MAE
    x_mae = df[(df["topic"] == "model_rov_pose") & (df["axis"] == "x") & (df["metric"] == "mae")]
    cell = {r["name"]: tuple(sorted(r["factors"].items())) for r in manifest["runs"]}
    spread = x_mae.groupby(x_mae["run"].map(cell))["value"].agg(lambda v: v.max() - v.min())
    assert len(spread) == 27 and (spread > 0).all()
    assert (out / "results" / "sensitivity.json").is_file()
