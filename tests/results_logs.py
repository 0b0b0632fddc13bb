"""Logs and experiment folders shaped as uwval writes them, shared by the results, gate and
report tests."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from uwval.frames import convert_arrays
from uwval.io.mcap_io import McapPoseWriter
from uwval.rotations import quat_from_rpy

VEHICLE, CAMERA = "model_rov_pose", "gui_camera_pose"


def write_pair_log(
    path: Path,
    *,
    speed: float = 1.0,
    yaw_rate: float = 0.2,
    lag_s: float = 0.0,
    noise: float = 0.0,
    duration: float = 4.0,
    seed: int = 0,
    camera: bool = True,
) -> Path:
    """A real MCAP log as uwval's recorder writes it: Gazebo poses in ENU at 50 Hz and the
    Unity side (ROS-TCP-Connector FLU map) at 60 Hz, showing the Gazebo pose ``lag_s`` late
    plus Gaussian position noise (m). The vehicle surges along a yawing heading; z is flat
    (its Pearson r is undefined on purpose)."""
    rng = np.random.default_rng(seed)

    def pose(ts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        yaw = yaw_rate * ts
        pos = np.stack([speed * ts, 0.3 * speed * np.sin(ts), np.full_like(ts, -2.0)], axis=1)
        rpy = np.stack([0.02 * np.sin(2 * ts), 0.01 * np.cos(ts), yaw], axis=1)
        return pos, quat_from_rpy(rpy)

    tg = np.arange(0.0, duration, 1 / 50)
    tu = np.arange(0.0, duration, 1 / 60)
    pg, qg = pose(tg)
    pu, qu = pose(np.clip(tu - lag_s, 0, None))
    pu = pu + rng.normal(0.0, noise, pu.shape) if noise else pu
    upos, uquat = convert_arrays(pu, qu, "enu", "unity-flu")
    with McapPoseWriter(path) as w:
        for topic in [VEHICLE, CAMERA] if camera else [VEHICLE]:
            off = np.array([-3.0, 0.0, 1.0]) if topic == CAMERA else 0.0
            w.write_poses(f"/gazebo/{topic}", (tg * 1e9).astype(np.int64), pg + off, qg, "enu")
            cu, cq = convert_arrays(pu + off, qu, "enu", "unity-flu")
            w.write_poses(
                f"/unity/{topic}",
                (tu * 1e9).astype(np.int64),
                cu if topic == CAMERA else upos,
                cq if topic == CAMERA else uquat,
                "unity-flu",
            )
    return path


def write_experiment(root: Path, *, compare: bool = True, reps: int = 2) -> Path:
    """An experiment directory like ``uwval simulate EXP -o DIR`` + batch compare write it:
    runs/<name>.mcap, manifest.json, and results/comparisons.json (when ``compare``).
    The factor "force" scales the speed; "current" adds a Unity lag (0.3 s per m/s), so it
    raises the error."""
    from uwval.comparison import compare_logs

    (root / "runs").mkdir(parents=True, exist_ok=True)
    runs: list[dict[str, Any]] = []
    comp_runs = []
    seed = 0
    for force in (5.0, 10.0):
        for current in (0.0, 0.2):
            for rep in range(reps):
                name = f"force{force:g}_current{current:g}_rep{rep}"
                log = write_pair_log(
                    root / "runs" / f"{name}.mcap",
                    speed=force / 10,
                    lag_s=0.02 + 0.3 * current,
                    noise=0.002,
                    seed=seed,
                )
                seed += 1
                factors = {"force": force, "torque": 0.0, "current": current}
                bridge = {"sent": 200, "dropped": rep, "latency_mean_ms": 20 + 100 * current}
                runs.append(
                    {
                        "name": name,
                        "log": f"runs/{log.name}",
                        "factors": factors,
                        "seed": seed,
                        "bridge": bridge,
                    }
                )
                if compare:
                    comp_runs.append(
                        {
                            "name": name,
                            "log": str(log),
                            "factors": factors,
                            "bridge": bridge,
                            "comparison": compare_logs(log).to_json(),
                        }
                    )
    (root / "manifest.json").write_text(
        json.dumps({"experiment": {"name": "test-factorial"}, "runs": runs, "failed": []})
    )
    if compare:
        (root / "results").mkdir(exist_ok=True)
        (root / "results" / "comparisons.json").write_text(
            json.dumps({"runs": comp_runs, "failed": []})
        )
    return root
