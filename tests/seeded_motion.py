"""Seeded pose streams shared by tests: a vehicle moving on a circle, with measurement noise."""

from __future__ import annotations

import numpy as np

from uwval.posestream import PoseStream


def moving_vehicle(seed: int, n: int = 300, shift_s: float = 0.0) -> PoseStream:
    """A moving vehicle (x, y and yaw move, 50 Hz from t = 1 s + ``shift_s``, ENU) with 2 mm /
    0.05 deg of seeded noise."""
    rng = np.random.default_rng(seed)
    t = np.arange(n, dtype=np.int64) * 20_000_000 + 1_000_000_000 + round(shift_s * 1e9)
    s = np.arange(n) * 0.01
    pos = np.stack([2 * np.cos(s), 2 * np.sin(s), np.full(n, -1.0)], axis=1)
    pos = pos + rng.normal(0, 0.002, (n, 3))
    yaw = s + np.radians(rng.normal(0, 0.05, n))
    quat = np.stack([np.zeros(n), np.zeros(n), np.sin(yaw / 2), np.cos(yaw / 2)], axis=1)
    return PoseStream.from_arrays(t, pos, quat, frame="enu")
