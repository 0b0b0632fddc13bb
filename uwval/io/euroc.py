"""EuRoC MAV ground truth: ``mav0/state_groundtruth_estimate0/data.csv``.

Comma-separated, ``#`` header; columns: timestamp (integer ns), p_RS_R x y z (m), q_RS w x y z,
then velocities and biases (ignored). As evo's ``read_euroc_csv_trajectory``: at least 8
columns, stamps taken from the first. Stamps are parsed as exact int64 ns (evo goes through a
float, which rounds 19-digit ns stamps to 256 ns). Quaternions are reordered to (x, y, z, w).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from uwval.errors import LogReadError
from uwval.io.kitti import data_line_numbers, first_bad_line
from uwval.posestream import PoseStream


def read_euroc(path: str | Path, *, frame: str = "enu", topic: str = "") -> PoseStream:
    """Read an EuRoC ground-truth CSV into a PoseStream (body pose in the world frame R)."""
    p = Path(path)
    if not p.is_file():
        raise LogReadError(f"{p}: no such file")
    try:
        m = np.loadtxt(p, comments="#", delimiter=",", ndmin=2, dtype=np.float64)
        t = np.loadtxt(p, comments="#", delimiter=",", ndmin=1, usecols=0, dtype=np.int64)
    except ValueError:
        raise LogReadError(first_bad_line(p, 8, ",", min_fields=True)) from None
    if m.shape[0] == 0:
        raise LogReadError(f"{p}: no poses (EuRoC ground truth: timestamp ns, x y z, qw qx qy qz)")
    if m.shape[1] < 8:
        raise LogReadError(
            f"{p} line 1: {m.shape[1]} fields, expected at least 8 "
            "(timestamp ns, p_RS_R x y z, q_RS w x y z)"
        )
    bad = ~np.isfinite(m[:, 1:8]).all(axis=1)
    if bad.any():
        line = int(data_line_numbers(p)[int(np.flatnonzero(bad)[0])])
        raise LogReadError(f"{p} line {line}: a position or quaternion value is not finite")
    if t.shape[0] > 1 and not bool(np.all(np.diff(t) > 0)):
        k = int(np.flatnonzero(np.diff(t) <= 0)[0]) + 1
        line = int(data_line_numbers(p)[k])
        raise LogReadError(f"{p} line {line}: timestamp {t[k]} ns does not increase")
    quat = np.ascontiguousarray(m[:, [5, 6, 7, 4]])
    return PoseStream.from_arrays(
        t, np.ascontiguousarray(m[:, 1:4]), quat, frame=frame, topic=topic, source=str(p)
    )
