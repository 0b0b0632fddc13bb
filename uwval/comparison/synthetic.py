"""Deterministic synthetic Gazebo/Unity pose pairs for tests, benchmarks and demos.

``vehicle_motion`` is a smooth 6-DOF ENU/FLU trajectory (a lawn-mower-ish path with full
yaw turns, so yaw crosses +/-180 deg, and small roll/pitch oscillations). ``unity_view`` plays
the Unity side: a render loop at its own rate that shows the latest Gazebo pose received
``latency`` seconds earlier (sample and hold), stamped with its own clock (``clock_offset``),
expressed in a Unity convention, and remembering the Gazebo stamp it applied.
``write_pair_log`` writes both into one MCAP exactly like uwval's recorder lays topics out.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from uwval.frames import convert_stream
from uwval.posestream import PoseStream
from uwval.rotations import quat_from_rpy


def vehicle_motion(
    n: int,
    rate_hz: float = 50.0,
    *,
    seed: int = 0,
    t0_ns: int = 0,
    topic: str = "/gazebo/model_rov_pose",
) -> PoseStream:
    """``n`` poses at ``rate_hz`` of a smoothly moving vehicle (ENU world, FLU body)."""
    rng = np.random.default_rng(seed)
    period_ns = round(1e9 / rate_hz)
    t = np.int64(t0_ns) + np.arange(n, dtype=np.int64) * np.int64(period_ns)
    s = (t - t[0]).astype(np.float64) * 1e-9
    ph = rng.uniform(0, 2 * np.pi, size=6)
    pos = np.column_stack(
        [
            3.0 * np.sin(0.11 * s + ph[0]) + 0.2 * s,
            2.0 * np.sin(0.07 * s + ph[1]),
            -5.0 + 0.8 * np.sin(0.05 * s + ph[2]),
        ]
    )
    rpy = np.column_stack(
        [
            0.15 * np.sin(0.3 * s + ph[3]),
            0.10 * np.sin(0.23 * s + ph[4]),
            0.35 * s + ph[5],  # keeps turning: yaw wraps through +/-180 deg
        ]
    )
    return PoseStream(
        t=t,
        position=pos,
        orientation=quat_from_rpy(rpy),
        frame="enu",
        topic=topic,
        source="synthetic",
    )


def unity_view(
    gazebo: PoseStream,
    *,
    convention: str = "unity-flu",
    rate_hz: float = 60.0,
    latency: float = 0.0,
    clock_offset: float = 0.0,
    noise: float = 0.0,
    seed: int = 1,
    topic: str = "/unity/model_rov_pose",
) -> PoseStream:
    """The Unity side of ``gazebo``: sample-and-hold render loop, own clock, Unity frame.

    Frame k is rendered at reference time tau_k = t0 + k / rate_hz and shows the newest Gazebo
    pose stamped <= tau_k - latency; it is stamped tau_k + clock_offset (Unity's clock).
    ``noise`` adds Gaussian position noise (m) before the frame conversion.
    """
    rng = np.random.default_rng(seed)
    start = gazebo.t[0] + np.int64(round(latency * 1e9))
    n = int((gazebo.t[-1] - start) * 1e-9 * rate_hz)
    tau = start + np.round(np.arange(n) * (1e9 / rate_hz)).astype(np.int64)
    idx = np.searchsorted(gazebo.t, tau - np.int64(round(latency * 1e9)), side="right") - 1
    keep = idx >= 0
    tau, idx = tau[keep], idx[keep]
    pos = gazebo.position[idx] + (rng.normal(0.0, noise, (idx.size, 3)) if noise else 0.0)
    enu = PoseStream(
        t=tau + np.int64(round(clock_offset * 1e9)),
        position=pos,
        orientation=gazebo.orientation[idx],
        frame="enu",
        topic=topic,
        source="synthetic",
        applied_stamp=gazebo.t[idx],
    )
    return convert_stream(enu, convention)


def write_pair_log(
    path: str | Path,
    gazebo: PoseStream,
    unity: PoseStream,
    camera: tuple[PoseStream, PoseStream] | None = None,
    frame_id: str | None = None,
) -> Path:
    """Write an MCAP like uwval's recorder: /gazebo/<name> (ENU), /unity/<name> (Unity frame,
    frame_id = convention unless ``frame_id`` overrides it) and /unity/<name>/applied_stamp.
    """
    from uwval.io.writers import open_writer, write_stream

    p = Path(path)
    pairs = [(gazebo, unity)] + ([camera] if camera else [])
    with open_writer(p, "mcap") as w:
        for g, u in pairs:
            write_stream(w, g.topic, g, "enu")
            write_stream(w, u.topic, u, frame_id if frame_id is not None else u.frame)
    return p


def camera_motion(vehicle: PoseStream, topic: str = "/gazebo/gui_camera_pose") -> PoseStream:
    """A camera following the vehicle 3 m behind and 1 m above it, looking the same way."""
    from uwval.rotations import rotate_vectors

    back = rotate_vectors(vehicle.orientation, np.tile([-3.0, 0.0, 1.0], (len(vehicle), 1)))
    return PoseStream(
        t=vehicle.t,
        position=vehicle.position + back,
        orientation=vehicle.orientation,
        frame="enu",
        topic=topic,
        source="synthetic",
    )
