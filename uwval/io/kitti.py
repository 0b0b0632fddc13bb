"""KITTI odometry pose files: 12 numbers per line, the 3 x 4 matrix [R | t] row-major.

KITTI files carry no stamps; like evo (``read_kitti_poses_file``, a path without stamps),
poses are numbered by line: pose k gets the stamp k seconds, so that two files pair up pose by
pose (and ``compare``'s association pairs k with k). Lines starting with ``#`` are comments.
Parsing is numpy's C text reader; a bad line is named (1-based line number) on the error path.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from uwval.errors import LogReadError
from uwval.posestream import PoseStream
from uwval.rotations import quat_from_matrix

F64 = NDArray[np.float64]

#: Largest |R R^T - I| entry accepted for a pose's rotation block (text rounding included).
ORTHONORMAL_TOLERANCE = 1e-3
_SECOND_NS = 1_000_000_000


def first_bad_line(path: Path, n_fields: int, sep: str | None, min_fields: bool = False) -> str:
    """Where a numeric text table goes wrong: '<path> line L: <what>' (error path only)."""
    with open(path, encoding="utf-8", errors="replace") as fh:
        for no, line in enumerate(fh, start=1):
            s = line.strip()
            if not s or s.startswith("#"):
                continue
            fields = [f.strip() for f in s.split(sep)]
            if (len(fields) < n_fields) if min_fields else (len(fields) != n_fields):
                want = f"at least {n_fields}" if min_fields else str(n_fields)
                return f"{path} line {no}: {len(fields)} fields, expected {want}"
            for f in fields:
                try:
                    float(f)
                except ValueError:
                    return f"{path} line {no}: {f!r} is not a number"
    return f"{path}: could not be parsed as a table of numbers"


def data_line_numbers(path: Path) -> NDArray[np.int64]:
    """1-based line numbers of the data lines (not blank, not '#'), for error messages."""
    raw = path.read_bytes().split(b"\n")
    keep = [k + 1 for k, ln in enumerate(raw) if ln.strip() and not ln.lstrip().startswith(b"#")]
    return np.asarray(keep, dtype=np.int64)


def read_kitti(path: str | Path, *, frame: str = "enu", topic: str = "") -> PoseStream:
    """Read a KITTI pose file into a PoseStream (stamps 0, 1, 2, ... s; one pose per line)."""
    p = Path(path)
    if not p.is_file():
        raise LogReadError(f"{p}: no such file")
    try:
        m = np.loadtxt(p, comments="#", ndmin=2, dtype=np.float64)
    except ValueError:
        raise LogReadError(first_bad_line(p, 12, None)) from None
    if m.shape[0] == 0:
        raise LogReadError(f"{p}: no poses (a KITTI file has 12 numbers per line)")
    if m.shape[1] != 12:
        raise LogReadError(f"{p} line 1: {m.shape[1]} fields, expected 12 (3 x 4 matrix [R | t])")
    bad = ~np.isfinite(m).all(axis=1)
    mats = m.reshape(-1, 3, 4)
    rot = mats[:, :, :3]
    err = np.abs(np.einsum("nij,nkj->nik", rot, rot) - np.eye(3)).max(axis=(1, 2))
    bad |= (err > ORTHONORMAL_TOLERANCE) | (np.linalg.det(rot) <= 0)
    if bad.any():
        k = int(np.flatnonzero(bad)[0])
        line = int(data_line_numbers(p)[k])
        what = (
            "a value is not finite"
            if not np.isfinite(m[k]).all()
            else f"the rotation block is not a rotation (|R R^T - I| = {err[k]:.3g})"
        )
        raise LogReadError(f"{p} line {line}: {what}")
    t = np.arange(m.shape[0], dtype=np.int64) * _SECOND_NS
    return PoseStream.from_arrays(
        t,
        np.ascontiguousarray(mats[:, :, 3]),
        quat_from_matrix(rot),
        frame=frame,
        topic=topic,
        source=str(p),
    )
