"""evo's text inputs besides TUM, ``--format kitti|euroc`` (user documentation: docs/formats.md).

``kitti``: 12 numbers a line ([R | t] row-major), no stamps: as in evo, pose k gets k seconds,
so two files pair line by line (equal counts). ``euroc``: EuRoC's ground-truth ``data.csv``
(ns, p_RS_R x y z, q_RS w x y z, ignored columns); as ``evo_ape euroc``, a .txt / .tum file of
the pair is TUM text. numpy's C text reader parses; a bad line is named on the error path.
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
    """Where a numeric text table goes wrong: '<path>: line L (byte offset B): <what>'."""
    from uwval.io.tum import data_lines

    for here, fields in data_lines(path.read_bytes(), None if sep is None else sep.encode()):
        if (len(fields) < n_fields) if at_least else (len(fields) != n_fields):
            want = f"at least {n_fields}" if at_least else str(n_fields)
            return f"{path}: {here}: {len(fields)} fields, expected {want}"
        for f in fields:
            try:
                float(f)
            except ValueError:
                return f"{path}: {here}: {f.decode(errors='replace')!r} is not a number"
    return f"{path}: could not be parsed as a table of numbers"


def _line_of_row(path: Path, row: int) -> str:
    """'line L (byte offset B)' of data row ``row`` (0-based; error path only)."""
    from uwval.io.tum import data_lines

    return next(here for k, (here, _) in enumerate(data_lines(path.read_bytes())) if k == row)


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
        raise LogReadError(f"{path}: line 1: {m.shape[1]} fields, expected {n_fields}")
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
        raise LogReadError(f"{p}: {_line_of_row(p, k)}: {what}")
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
        raise LogReadError(f"{p}: {line}: a position or quaternion value is not finite")
    if t.shape[0] > 1 and not bool(np.all(np.diff(t) > 0)):
        k = int(np.flatnonzero(np.diff(t) <= 0)[0]) + 1
        raise LogReadError(f"{p}: {_line_of_row(p, k)}: timestamp {t[k]} ns does not increase")
    quat = np.ascontiguousarray(m[:, [5, 6, 7, 4]])
    return PoseStream.from_arrays(
        t, np.ascontiguousarray(m[:, 1:4]), quat, frame=frame, topic=topic, source=str(p)
    )


def read_evo_text(path: str | Path, fmt: str, *, frame: str = "enu", topic: str = "") -> PoseStream:
    """One trajectory file in evo's ``kitti`` or ``euroc`` layout (see the module doc)."""
    if fmt == "kitti":
        return read_kitti(path, frame=frame, topic=topic)
    if fmt == "euroc":
        from uwval.io.formats import TUM_SUFFIXES
        from uwval.io.tum import read_tum

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
