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

    Raises :class:`LogReadError` naming the first malformed line (1-based).
    """
    table = _parse_whole(data, source)
    return (ns_from_seconds(table[:, 0]), np.ascontiguousarray(table[:, 1:4]),
            np.ascontiguousarray(table[:, 4:8]))


def _first_bad_line(data: bytes, strict: bool = False) -> str:
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
    return "" if strict else "malformed TUM file (could not parse as numbers)"


_CHUNK = 1 << 22  # bytes parsed per numpy call: bounds the text held in memory at once


def parse_tum_file(path: Path) -> NDArray[np.float64]:
    """Parse a TUM file into an (N, 8) float64 table, chunk by chunk.

    Only about ``_CHUNK`` bytes of text are held at a time (plain reads: an mmap would count
    the whole file as resident memory) and the table is sized from the first chunk's bytes
    per line, so peak memory is about the table itself. Leading comment lines are skipped;
    files with comments further down take the whole-text path. Any line that is not 8
    numbers raises :class:`LogReadError` naming the line and its byte offset.
    """
    with open(path, "rb") as fh:
        size = fh.seek(0, 2)
        if size == 0:
            raise LogReadError(f"{path}: file is empty")
        fh.seek(0)
        head = fh.read(_CHUNK)
        start = 0
        while start < len(head):  # skip blank and comment lines at the top
            end = head.find(b"\n", start)
            end = len(head) if end < 0 else end + 1
            if head[start:end].strip()[:1] not in (b"", b"#"):
                break
            start = end
        body = head[start:]
        per_line = max(1.0, len(body) / max(1, body.count(b"\n")))
        table = np.empty((int((size - start) / per_line * 1.05) + 16, 8), dtype=np.float64)
        rows = 0
        carry = body
        while True:
            more = fh.read(_CHUNK) if len(carry) < _CHUNK or not carry.endswith(b"\n") else b""
            text = carry + more if more else carry
            if not text:
                break
            if more:
                cut = text.rfind(b"\n") + 1
                if cut == 0:  # no newline yet: a very long line, read on
                    carry = text
                    continue
                text, carry = text[:cut], text[cut:]
            else:
                carry = b""
            if b"#" in text:
                fh.seek(0)
                return _parse_whole(fh.read(), str(path))
            try:
                values = np.fromstring(text, dtype=np.float64, sep=" ")
            except ValueError:
                values = np.empty(1)  # not numbers: located on the whole-text path
            k = values.size // 8
            if values.size % 8 or (k != text.count(b"\n") and k != _nonblank_lines(text)):
                fh.seek(0)
                return _parse_whole(fh.read(), str(path))
            if rows + k > table.shape[0]:
                table = np.resize(table, (2 * (rows + k), 8))
            table[rows:rows + k] = values.reshape(k, 8)
            rows += k
            del values, text
    if rows == 0:
        raise LogReadError(f"{path}: no poses (empty TUM file)")
    return table[:rows]


def _nonblank_lines(text: bytes) -> int:
    lines = text.count(b"\n") + (0 if text.endswith(b"\n") else 1)
    return lines - text.count(b"\n\n") - (1 if text.startswith(b"\n") else 0)


def _parse_whole(data: bytes, source: str) -> NDArray[np.float64]:
    """Slow but thorough path: comments anywhere, blank lines, exact error location."""
    body = _COMMENT.sub(b"", data) if b"#" in data else data
    try:
        values = np.fromstring(body, dtype=np.float64, sep=" ")
    except ValueError:  # a token that is not a number
        raise LogReadError(f"{source}: {_first_bad_line(data)}") from None
    n_tokens = len(body.split())
    if values.size % 8 or n_tokens != values.size:
        raise LogReadError(f"{source}: {_first_bad_line(data)}")
    bad = _first_bad_line(data, strict=True) if values.size else None
    if bad:
        raise LogReadError(f"{source}: {bad}")
    if values.size == 0:
        raise LogReadError(f"{source}: no poses (empty TUM file)")
    return values.reshape(-1, 8)


def read_tum(path: str | Path, *, frame: str = "enu", topic: str = "") -> PoseStream:
    """Read a TUM trajectory file into a :class:`PoseStream` (stamps in ns, frame ``frame``).

    Unsorted or duplicate stamps and slightly non-unit quaternions are repaired and counted in
    ``stream.repairs``; NaN values and badly non-unit quaternions raise errors naming the file.
    Clean files (the common case) skip the repair pass: positions and orientations stay
    views of the parsed table, so a 360,000-pose file costs one 23 MB table.
    """
    p = Path(path)
    if not p.exists():
        raise LogReadError(f"{p}: no such file or directory")
    try:
        table = parse_tum_file(p)
    except OSError as exc:
        raise LogReadError(f"{p}: cannot read: {exc}") from exc
    t = ns_from_seconds(table[:, 0])
    pos, quat = table[:, 1:4], table[:, 4:8]
    name = topic or "tum"
    if _clean(t, table, quat):
        return PoseStream(t=t, position=pos, orientation=quat, frame=frame, topic=name,
                          source=str(p))
    # something needs repair: first make sure it is not a misparse (a line of 7 numbers next
    # to one of 9 keeps the token count a multiple of 8 but scrambles columns)
    bad = _first_bad_line(p.read_bytes(), strict=True)
    if bad:
        raise LogReadError(f"{p}: {bad}")
    try:
        return PoseStream.from_arrays(t, pos, quat, frame=frame, topic=name, source=str(p))
    except PoseStreamError as exc:
        raise PoseStreamError(f"{exc} (TUM file: sample k is on the k-th pose line)") from None


def _clean(t: I64, table: F64, quat: F64) -> bool:
    """True when nothing needs repairing: finite, strictly increasing, unit quaternions."""
    if not bool(np.isfinite(table).all()):
        return False
    if t.size > 1 and not bool((np.diff(t) > 0).all()):
        return False
    norm2 = np.einsum("ij,ij->i", quat, quat)
    return bool(np.abs(norm2 - 1.0).max() <= 2e-9)


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
