"""TUM trajectory text files: ``timestamp tx ty tz qx qy qz qw`` per line (evo's format).

One reading path: the bytes are checked against the format's one separator rule, then
parsed by pandas' C reader (correctly rounded: every value is the double ``float()`` gives).
The rules, the same for every file:

* fields are separated by spaces and tabs; lines end in LF or CRLF; ``#`` starts a comment
  (a whole line, indented or not, or the rest of a line); blank lines are skipped;
* any other byte outside a comment (a no-break space 0xA0, a control byte such as 0x1C or
  0x0B, a carriage return inside a line, any non-ASCII byte) is refused, naming the line and
  byte offset: such a byte is a damaged or foreign file, never a separator;
* a data line holds exactly 8 finite numbers; anything else is refused naming the line.

Stamps become int64 nanoseconds by an exact split of each double (:func:`ns_from_seconds`),
so :func:`seconds_from_ns` gives back bit for bit the double evo parses. Quaternions rounded
to a few decimals (TUM RGB-D ground truths have 4) are normalised and counted in
``repairs['renormalized']``; beyond ``QUAT_NORM_TOLERANCE`` they are refused naming the line.
Poses are taken as ENU/FLU unless the caller states another convention.
"""

from __future__ import annotations

import csv
import io
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from uwval.errors import LogReadError, LogWriteError, PoseStreamError
from uwval.io.formats import TUM_SUFFIXES
from uwval.io.stamps import NS_PER_S, ns_from_seconds, seconds_from_ns
from uwval.posestream import QUAT_NORM_TOLERANCE, PoseStream

__all__ = [
    "TUM_SUFFIXES",
    "ns_from_seconds",
    "read_tum",
    "read_tum_pair",
    "seconds_from_ns",
    "write_tum",
]

F64 = NDArray[np.float64]
I64 = NDArray[np.int64]

#: The columns of a TUM line, as error messages name them.
COLUMNS = ("timestamp", "tx", "ty", "tz", "qx", "qy", "qz", "qw")
#: int64 nanoseconds reach 2**63 ns ~ 9.22e9 s (year 2262).
MAX_STAMP_S = 9.2e9

_BOM = b"\xef\xbb\xbf"
#: Bytes that may appear outside comments besides printable ASCII: tab, LF, CR (before LF).
_STRAY = np.ones(256, dtype=bool)
_STRAY[0x20:0x7F] = False
_STRAY[[0x09, 0x0A, 0x0D]] = False


def _stray_byte(data: bytes) -> int:
    """Offset of the first byte outside a comment that the format does not allow, or -1.

    Vectorised: one table look-up over the bytes finds the candidates (usually none); only
    those are then checked for lying in a comment (after a ``#`` on their line).
    """
    b = np.frombuffer(data, dtype=np.uint8)
    allowed = data.count(b"\n") + data.count(b"\t") + data.count(b"\r")
    clean = data.isascii() and b"\x7f" not in data and np.count_nonzero(b < 0x20) == allowed
    cand = None if clean else np.flatnonzero(_STRAY[b])
    cr = data.find(b"\r")
    if cr >= 0:  # a CR must end a line (CRLF)
        crs = np.flatnonzero(b == 0x0D)
        after = b[np.minimum(crs + 1, b.size - 1)]
        bare = crs[(crs + 1 >= b.size) | (after != 0x0A)]
        cand = bare if cand is None else np.union1d(cand, bare)
    if cand is None or cand.size == 0:
        return -1
    for off in cand.tolist():  # few: a file is refused at the first that is not in a comment
        start = data.rfind(b"\n", 0, off) + 1
        if data.find(b"#", start, off) < 0:
            return int(off)
    return -1


def _describe_byte(value: int) -> str:
    """How an error message names a refused byte."""
    if value == 0x0D:
        return "a carriage return inside the line"
    names = {0xA0: " (no-break space)", 0x1C: " (file separator)", 0x0B: " (vertical tab)"}
    return f"byte 0x{value:02X}{names.get(value, '')}"


def _where(data: bytes, offset: int) -> str:
    """'line L (byte offset B)' of a byte offset (1-based line numbers)."""
    line = data.count(b"\n", 0, offset) + 1
    return f"line {line} (byte offset {offset})"


def _check_bytes(data: bytes, path: Path) -> None:
    """Refuse a byte the format does not allow outside comments (see the module doc)."""
    off = _stray_byte(data)
    if off >= 0:
        raise LogReadError(
            f"{path}: {_where(data, off)}: {_describe_byte(data[off])}: refused (TUM fields "
            "are separated by spaces or tabs; a line ends in LF or CRLF)"
        )


def _unindent_comments(data: bytes) -> bytes:
    """``data`` with the indentation of indented comment lines turned into ``#`` (same offsets).

    pandas takes ``  # text`` as a row of empty fields; ``### text`` is a comment line.
    """
    b = np.frombuffer(data, dtype=np.uint8)
    hashes = np.flatnonzero(b == 0x23)
    if hashes.size == 0:
        return data
    out: bytearray | None = None
    for at in hashes.tolist():  # comment lines: few (a header), each checked once
        start = at
        while start > 0 and data[start - 1] in (0x20, 0x09):
            start -= 1
        if start < at and (start == 0 or data[start - 1] == 0x0A):
            out = bytearray(data) if out is None else out
            out[start:at] = b"#" * (at - start)
    return data if out is None else bytes(out)


def _first_bad_line(data: bytes) -> str:
    """What is wrong with the first data line that is not 8 finite numbers (error path only)."""
    offset = 0
    for lineno, line in enumerate(data.split(b"\n"), start=1):
        fields = line.split(b"#", 1)[0].split()
        here = f"line {lineno} (byte offset {offset})"
        offset += len(line) + 1
        if not fields:
            continue
        if len(fields) != 8:
            text = line.strip()[:80].decode("ascii", "replace")
            return (
                f"{here}: expected 8 numbers '{' '.join(COLUMNS)}', "
                f"got {len(fields)} fields: {text!r}"
            )
        for name, tok in zip(COLUMNS, fields, strict=True):
            try:
                value = float(tok) if b"_" not in tok else None
            except ValueError:
                value = None
            if value is None:
                return f"{here}: {name} {tok.decode('ascii', 'replace')!r} is not a number"
            if not np.isfinite(value) or (name == "timestamp" and abs(value) >= MAX_STAMP_S):
                what = "a finite time in seconds (|t| < 9.2e9)" if name == "timestamp" else ""
                return f"{here}: {name} {tok.decode()!r} is not {what or 'a finite number'}"
    return ""


def _data_line(data: bytes, row: int) -> str:
    """'line L (byte offset B)' of the ``row``-th data line (0-based; error path only)."""
    offset = 0
    for lineno, line in enumerate(data.split(b"\n"), start=1):
        if line.split(b"#", 1)[0].strip():
            if row == 0:
                return f"line {lineno} (byte offset {offset})"
            row -= 1
        offset += len(line) + 1
    return f"data line {row + 1}"


def _parse(data: bytes, path: Path) -> tuple[F64, F64, F64]:
    """Stamps (N,) in s, positions (N, 3) and quaternions (N, 4) of a TUM text whose bytes
    passed :func:`_check_bytes`."""
    import pandas as pd

    # pandas >= 3.1 converts exactly by default (and deprecates the option); older ones
    # need the round-trip converter for float()'s doubles
    exact: dict[str, Any] = {}
    if tuple(map(int, pd.__version__.split(".")[:2])) < (3, 1):
        exact["float_precision"] = "round_trip"
    try:
        frame = pd.read_csv(
            io.BytesIO(_unindent_comments(data)),
            sep=r"\s+",
            header=None,
            comment="#",
            dtype=np.float64,
            na_filter=False,  # "NA", "" are not numbers
            quoting=csv.QUOTE_NONE,
            engine="c",
            **exact,
        )
    except pd.errors.EmptyDataError:
        raise LogReadError(f"{path}: no poses (empty TUM file)") from None
    except (ValueError, pd.errors.ParserError) as exc:  # ParserError is a ValueError
        bad = _first_bad_line(data) or f"cannot parse: {' '.join(str(exc).split())}"
        raise LogReadError(f"{path}: {bad}") from None
    if frame.shape[1] != 8:
        raise LogReadError(f"{path}: {_first_bad_line(data) or 'not 8 columns'}")
    # the parser's own column arrays (no (N, 8) copy): stamps, position, quaternion
    cols = [np.asarray(frame[k].to_numpy(), dtype=np.float64) for k in frame.columns]
    finite = all(np.isfinite(c.min() + c.max()) for c in cols)  # NaN and inf propagate
    if not finite or max(abs(float(cols[0].min())), abs(float(cols[0].max()))) >= MAX_STAMP_S:
        raise LogReadError(f"{path}: {_first_bad_line(data)}")
    return cols[0], np.column_stack(cols[1:4]), np.column_stack(cols[4:8])


def _load(p: Path, frame: str, topic: str) -> PoseStream:
    """Read, check and parse one TUM file into a repaired :class:`PoseStream`."""
    if not p.exists():
        raise LogReadError(f"{p}: no such file or directory")
    try:
        data = p.read_bytes()
    except OSError as exc:
        raise LogReadError(f"{p}: cannot read: {exc}") from exc
    if not data:
        raise LogReadError(f"{p}: file is empty")
    if data.startswith(_BOM):  # written by Windows tools: blank it, keeping byte offsets
        data = b"   " + data[3:]
    _check_bytes(data, p)
    stamps, position, quat = _parse(data, p)
    if stamps.shape[0] == 0:
        raise LogReadError(f"{p}: no poses (empty TUM file)")
    norms = np.sqrt(np.einsum("ij,ij->i", quat, quat))
    off = np.abs(norms - 1.0)
    if float(off.max()) > QUAT_NORM_TOLERANCE:
        k = int(np.argmax(off > QUAT_NORM_TOLERANCE))
        raise LogReadError(
            f"{p}: {_data_line(data, k)}: quaternion qx qy qz qw has norm {norms[k]:.6g}, "
            f"more than {QUAT_NORM_TOLERANCE} from 1: refused (is it x, y, z, w order?)"
        )
    try:
        return PoseStream.from_arrays(
            ns_from_seconds(stamps),
            position,
            quat,
            frame=frame,
            topic=topic or "tum",
            source=str(p),
        )
    except PoseStreamError as exc:  # e.g. stamps whose span overflows int64
        raise LogReadError(f"{p}: {exc}") from None


def read_tum(path: str | Path, *, frame: str = "enu", topic: str = "") -> PoseStream:
    """Read a TUM trajectory file into a :class:`PoseStream` (stamps in ns, frame ``frame``).

    Unsorted or duplicate stamps and slightly non-unit quaternions are repaired and counted in
    ``stream.repairs``; anything else wrong raises :class:`LogReadError` naming the file, the
    line and what is wrong.
    """
    return _load(Path(path), frame, topic)


def read_tum_pair(
    path_a: str | Path,
    path_b: str | Path,
    *,
    frame_a: str = "enu",
    frame_b: str = "enu",
    topic_a: str = "",
    topic_b: str = "",
) -> tuple[PoseStream, PoseStream]:
    """Read two TUM files, one after the other (the first file's error wins)."""
    return (
        read_tum(path_a, frame=frame_a, topic=topic_a),
        read_tum(path_b, frame=frame_b, topic=topic_b),
    )


def write_tum(path: str | Path, stream: PoseStream, *, precision: int = 9) -> None:
    """Write ``stream`` as a TUM file (stamps in seconds with 9 decimals: exact ns).

    Poses are written as they are stored (in the stream's own frame convention).
    """
    p = Path(path)
    whole, frac = np.divmod(stream.t, NS_PER_S)
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
