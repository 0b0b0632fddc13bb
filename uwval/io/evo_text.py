"""evo's text inputs besides TUM: KITTI pose files and EuRoC ground truth (``--format``).

``kitti``: 12 numbers per line, the 3 x 4 matrix [R | t] row-major, no stamps. As evo does,
pose k gets the stamp k seconds, so two files pair up pose by pose and must hold the same
number of poses. ``euroc``: ``mav0/state_groundtruth_estimate0/data.csv``, comma-separated
with a ``#`` header: timestamp (integer ns), p_RS_R x y z (m), q_RS w x y z, then columns
that are ignored; as ``evo_ape euroc GT.csv EST.txt``, a file with a TUM suffix (.txt / .tum)
is TUM text. Parsing is numpy's C text reader; a bad line is named (1-based) on the error path.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from uwval.errors import AlignmentError, ConfigError, LogReadError
from uwval.posestream import PoseStream
from uwval.rotations import quat_from_matrix

EVO_TEXT_FORMATS = ("kitti", "euroc")
#: Largest |R R^T - I| entry accepted for a KITTI rotation block (text rounding included).
ORTHONORMAL_TOLERANCE = 1e-3


def _first_bad_line(path: Path, n_fields: int, sep: str | None, at_least: bool = False) -> str:
    """Where a numeric text table goes wrong: '<path> line L: <what>' (error path only)."""
    with open(path, encoding="utf-8", errors="replace") as fh:
        for no, line in enumerate(fh, start=1):
            if not line.strip() or line.strip().startswith("#"):
                continue
            fields = [f.strip() for f in line.strip().split(sep)]
            if (len(fields) < n_fields) if at_least else (len(fields) != n_fields):
                want = f"at least {n_fields}" if at_least else str(n_fields)
                return f"{path} line {no}: {len(fields)} fields, expected {want}"
            for f in fields:
                try:
                    float(f)
                except ValueError:
                    return f"{path} line {no}: {f!r} is not a number"
    return f"{path}: could not be parsed as a table of numbers"


def _line_of_row(path: Path, row: int) -> int:
    """1-based line number of data row ``row`` (not blank, not '#'; error path only)."""
    lines = path.read_bytes().split(b"\n")
    data = [k + 1 for k, ln in enumerate(lines) if ln.strip() and not ln.lstrip().startswith(b"#")]
    return data[row]


def _table(path: Path, n_fields: int, sep: str | None) -> NDArray[np.float64]:
    """The numbers of a text table, at least ``n_fields`` per line (``sep=None``: exactly)."""
    if not path.is_file():
        raise LogReadError(f"{path}: no such file")
    try:
        m = np.loadtxt(path, comments="#", delimiter=sep, ndmin=2, dtype=np.float64)
    except ValueError:
        raise LogReadError(_first_bad_line(path, n_fields, sep, sep is not None)) from None
    if m.shape[0] == 0:
        raise LogReadError(f"{path}: no poses (expected {n_fields} numbers per line)")
    if m.shape[1] < n_fields or (sep is None and m.shape[1] != n_fields):
        raise LogReadError(f"{path} line 1: {m.shape[1]} fields, expected {n_fields}")
    return m


def read_kitti(path: str | Path, *, frame: str = "enu", topic: str = "") -> PoseStream:
    """Read a KITTI pose file into a PoseStream (stamps 0, 1, 2, ... s; one pose per line)."""
    p = Path(path)
    m = _table(p, 12, None)
    rot = m.reshape(-1, 3, 4)[:, :, :3]
    err = np.abs(np.einsum("nij,nkj->nik", rot, rot) - np.eye(3)).max(axis=(1, 2))
    finite: NDArray[np.bool_] = np.asarray(np.isfinite(m).all(axis=1))
    bad = ~finite | ~(err <= ORTHONORMAL_TOLERANCE) | (np.linalg.det(rot) <= 0)
    if bad.any():
        k = int(np.flatnonzero(bad)[0])
        what = f"the rotation block is not a rotation (|R R^T - I| = {err[k]:.3g})"
        what = what if finite[k] else "a value is not finite"
        raise LogReadError(f"{p} line {_line_of_row(p, k)}: {what}")
    t = np.arange(m.shape[0], dtype=np.int64) * 1_000_000_000
    pos = np.ascontiguousarray(m[:, [3, 7, 11]])
    return PoseStream.from_arrays(
        t, pos, quat_from_matrix(rot), frame=frame, topic=topic, source=str(p)
    )


def read_euroc(path: str | Path, *, frame: str = "enu", topic: str = "") -> PoseStream:
    """Read an EuRoC ground-truth CSV into a PoseStream (body pose in the world frame R).

    Stamps are parsed as exact int64 ns (evo goes through a float, which rounds 19-digit ns
    stamps to 256 ns); quaternions are reordered to (x, y, z, w).
    """
    p = Path(path)
    m = _table(p, 8, ",")
    t = np.loadtxt(p, comments="#", delimiter=",", ndmin=1, usecols=0, dtype=np.int64)
    bad = ~np.isfinite(m[:, 1:8]).all(axis=1)
    if bad.any():
        line = _line_of_row(p, int(np.flatnonzero(bad)[0]))
        raise LogReadError(f"{p} line {line}: a position or quaternion value is not finite")
    if t.shape[0] > 1 and not bool(np.all(np.diff(t) > 0)):
        k = int(np.flatnonzero(np.diff(t) <= 0)[0]) + 1
        raise LogReadError(f"{p} line {_line_of_row(p, k)}: timestamp {t[k]} ns does not increase")
    quat = np.ascontiguousarray(m[:, [5, 6, 7, 4]])
    return PoseStream.from_arrays(
        t, np.ascontiguousarray(m[:, 1:4]), quat, frame=frame, topic=topic, source=str(p)
    )


def read_evo_text(path: str | Path, fmt: str, *, frame: str = "enu", topic: str = "") -> PoseStream:
    """One trajectory file in evo's ``kitti`` or ``euroc`` layout (see the module doc)."""
    if fmt == "kitti":
        return read_kitti(path, frame=frame, topic=topic)
    if fmt == "euroc":
        from uwval.io.tum import TUM_SUFFIXES, read_tum

        if Path(path).suffix.lower() in TUM_SUFFIXES:
            return read_tum(path, frame=frame, topic=topic)
        return read_euroc(path, frame=frame, topic=topic)
    raise ConfigError(f"--format {fmt!r}: not one of {', '.join(EVO_TEXT_FORMATS)}")


def read_evo_pair(
    path_a: str | Path, path_b: str | Path, fmt: str, *, frame_b: str = "enu"
) -> tuple[PoseStream, PoseStream]:
    """The reference and the other trajectory; KITTI files must have equal pose counts."""
    a = read_evo_text(path_a, fmt)
    b = read_evo_text(path_b, fmt, frame=frame_b)
    if fmt == "kitti" and len(a) != len(b):
        raise AlignmentError(
            f"KITTI files pair poses by line: {path_a} has {len(a)} poses, {path_b} {len(b)}"
        )
    return a, b
