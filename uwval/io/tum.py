"""TUM trajectory text files: ``timestamp tx ty tz qx qy qz qw`` per line (evo's format).

The reader is vectorised: one ``numpy.fromstring`` call parses the whole file (no per-line
Python loop), comment lines (``#``) are removed first, and the stamp column is turned into
int64 nanoseconds by an exact split of each double into whole seconds and fraction, so that
converting back with :func:`seconds_from_ns` gives bit-for-bit the double evo parses
(which keeps evo-compatible stamp association exact). Poses are taken as ENU/FLU unless the
caller states another convention.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from uwval.errors import LogReadError, LogWriteError, PoseStreamError
from uwval.posestream import PoseStream

F64 = NDArray[np.float64]
I64 = NDArray[np.int64]

#: Suffixes taken as TUM text when no format is given.
TUM_SUFFIXES = (".tum", ".txt")

_COMMENT = re.compile(rb"(?m)^[ \t]*#[^\n]*(\n|$)")
_NS = 1_000_000_000


def ns_from_seconds(seconds: F64) -> I64:
    """Float seconds -> int64 ns, splitting off the whole seconds exactly first.

    ``s - floor(s)`` is exact for doubles, so the only rounding is of the fraction times 1e9
    (error < 1e-6 ns); the result is the integer nanosecond nearest to the double itself.
    """
    s = np.asarray(seconds, dtype=np.float64)
    whole = np.floor(s)
    frac_ns = np.rint((s - whole) * 1e9).astype(np.int64)
    return whole.astype(np.int64) * _NS + frac_ns


def seconds_from_ns(t: I64) -> F64:
    """Int64 ns -> float seconds, the double nearest to ``t / 1e9`` (whole part added last).

    For stamps parsed by :func:`ns_from_seconds` this returns exactly the parsed double, so
    evo-style float comparisons on seconds see the same numbers evo sees.
    """
    t = np.asarray(t, dtype=np.int64)
    # below 2^53 ns (104 days) the int is an exact double: one correctly rounded division
    small = np.abs(t) < (1 << 53)
    if small.all():
        return np.asarray(t.astype(np.float64) / 1e9)
    whole, frac = np.divmod(t, _NS)
    out = whole.astype(np.float64) + frac.astype(np.float64) / 1e9
    if small.any():
        out[small] = t[small].astype(np.float64) / 1e9
    return np.asarray(out)


def parse_tum_bytes(data: bytes, source: str = "<bytes>") -> tuple[I64, F64, F64]:
    """Parse TUM text into (t ns, position (N, 3), quaternion (N, 4) xyzw) arrays.

    Raises :class:`LogReadError` naming the first malformed line (1-based) when a line does
    not hold exactly 8 numbers.
    """
    body = _COMMENT.sub(b"", data) if b"#" in data else data
    try:
        values = np.fromstring(body, dtype=np.float64, sep=" ")
    except ValueError:  # a token that is not a number
        raise LogReadError(f"{source}: {_first_bad_line(data)}") from None
    n_tokens = len(body.split()) if values.size % 8 else values.size
    if values.size % 8 or n_tokens != values.size:
        raise LogReadError(f"{source}: {_first_bad_line(data)}")
    table = values.reshape(-1, 8)
    if table.shape[0] == 0:
        raise LogReadError(f"{source}: no poses (empty TUM file)")
    t = ns_from_seconds(table[:, 0])
    return t, np.ascontiguousarray(table[:, 1:4]), np.ascontiguousarray(table[:, 4:8])


def _first_bad_line(data: bytes) -> str:
    """Locate the first line that is not 8 numbers (slow path, only after a parse failure)."""
    offset = 0
    for lineno, line in enumerate(data.split(b"\n"), start=1):
        stripped = line.strip()
        if stripped and not stripped.startswith(b"#"):
            fields = stripped.replace(b",", b" ").split()
            ok = len(fields) == 8
            if ok:
                try:
                    [float(f) for f in fields]
                except ValueError:
                    ok = False
            if not ok:
                text = stripped[:60].decode(errors="replace")
                return (
                    f"line {lineno} (byte offset {offset}): expected 8 numbers "
                    f"'timestamp tx ty tz qx qy qz qw', got {text!r}"
                )
        offset += len(line) + 1
    return "malformed TUM file (could not parse as numbers)"


def read_tum(path: str | Path, *, frame: str = "enu", topic: str = "") -> PoseStream:
    """Read a TUM trajectory file into a :class:`PoseStream` (stamps in ns, frame ``frame``).

    Unsorted or duplicate stamps and slightly non-unit quaternions are repaired and counted in
    ``stream.repairs``; NaN values and badly non-unit quaternions raise errors naming the file.
    """
    p = Path(path)
    try:
        data = p.read_bytes()
    except FileNotFoundError:
        raise LogReadError(f"{p}: no such file or directory") from None
    except OSError as exc:
        raise LogReadError(f"{p}: cannot read: {exc}") from exc
    if not data.strip():
        raise LogReadError(f"{p}: file is empty")
    t, pos, quat = parse_tum_bytes(data, str(p))
    del data
    try:
        return PoseStream.from_arrays(t, pos, quat, frame=frame, topic=topic or "tum",
                                      source=str(p))
    except PoseStreamError as exc:
        raise PoseStreamError(f"{exc} (TUM file: sample k is on the k-th pose line)") from None


def write_tum(path: str | Path, stream: PoseStream, *, precision: int = 9) -> None:
    """Write ``stream`` as a TUM file (stamps in seconds with 9 decimals: exact ns).

    Poses are written as they are stored (in the stream's own frame convention).
    """
    p = Path(path)
    whole, frac = np.divmod(stream.t, _NS)
    body = np.column_stack([stream.position, stream.orientation])
    fmt = " ".join([f"%.{precision}f"] * 7)
    try:
        with open(p, "w", encoding="ascii") as fh:
            fh.write("# timestamp tx ty tz qx qy qz qw\n")
            # one formatted string per row: writing is not a hot path, parsing is
            fh.writelines(
                f"{w}.{f:09d} {fmt % tuple(row)}\n"
                for w, f, row in zip(whole.tolist(), frac.tolist(), body.tolist(), strict=True)
            )
    except OSError as exc:
        raise LogWriteError(f"{p}: cannot write: {exc}") from exc
