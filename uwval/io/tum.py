"""TUM trajectory text files: ``timestamp tx ty tz qx qy qz qw`` per line (evo's format).

One reading path: the bytes are checked against one separator rule (fields are separated by
spaces and tabs, lines end in LF or CRLF, ``#`` starts a comment; any other byte outside a
comment, such as 0xA0 or 0x1C, is refused naming the line and byte offset), then parsed by
numpy's C text reader, correctly rounded (every value is the double ``float()`` gives). Stamps
become int64 ns by an exact split of each double (:func:`ns_from_seconds`), so
:func:`seconds_from_ns` gives back the double evo parses. Rounded quaternions are normalised
and counted; every refusal names the line (docs/formats.md has the rules for users).
"""

from __future__ import annotations

import io
from collections.abc import Iterator
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from uwval.errors import LogReadError, LogWriteError, PoseStreamError
from uwval.io.stamps import NS_PER_S, ns_from_seconds, seconds_from_ns
from uwval.posestream import QUAT_NORM_TOLERANCE, PoseStream

__all__ = ["ns_from_seconds", "read_tum", "read_tum_pair", "seconds_from_ns", "write_tum"]

F64 = NDArray[np.float64]

#: The columns of a TUM line, as error messages name them.
COLUMNS = ("timestamp", "tx", "ty", "tz", "qx", "qy", "qz", "qw")
#: int64 nanoseconds reach 2**63 ns ~ 9.22e9 s (year 2262).
MAX_STAMP_S = 9.2e9
#: Bytes refused outside comments: all but printable ASCII, tab, LF and CR (CR only before LF).
_STRAY = np.ones(256, dtype=bool)
_STRAY[0x20:0x7F] = False
_STRAY[[0x09, 0x0A, 0x0D]] = False
_ALLOWED = bytes(np.flatnonzero(~_STRAY).astype(np.uint8))
_BYTE_NAMES = {0xA0: " (no-break space)", 0x1C: " (file separator)", 0x0B: " (vertical tab)"}


def _stray_byte(data: bytes) -> int:
    """Offset of the first byte outside a comment that the format does not allow, or -1.

    Vectorised: one pass drops the allowed bytes (usually leaving none); only the candidates
    left are then checked for lying in a comment (after a ``#`` on their line).
    """
    b = np.frombuffer(data, dtype=np.uint8)
    clean = not data.translate(None, _ALLOWED)  # one C pass; usually nothing is left
    cand = np.zeros(0, dtype=np.intp) if clean else np.flatnonzero(_STRAY[b])
    if b"\r" in data:  # a CR must end a line (CRLF)
        crs = np.flatnonzero(b == 0x0D)
        cand = np.union1d(cand, crs[b[np.minimum(crs + 1, b.size - 1)] != 0x0A])
        cand = np.union1d(cand, crs[crs + 1 == b.size])
    for off in cand.tolist():  # few: the file is refused at the first outside a comment
        if data.find(b"#", data.rfind(b"\n", 0, off) + 1, off) < 0:
            return int(off)
    return -1


def data_lines(data: bytes, sep: bytes | None = None) -> Iterator[tuple[str, list[bytes]]]:
    """('line L (byte offset B)', fields split at ``sep``, default blanks) of each line that
    holds data once its comment is cut off (error paths only; also evo_text's)."""
    offset = 0
    for lineno, line in enumerate(data.split(b"\n"), start=1):
        content = line.split(b"#", 1)[0]
        if content.strip():
            yield f"line {lineno} (byte offset {offset})", [f.strip() for f in content.split(sep)]
        offset += len(line) + 1


def _first_bad_line(data: bytes) -> str:
    """What is wrong with the first data line that is not 8 finite numbers (error path)."""
    for here, fields in data_lines(data):
        if len(fields) != 8:
            text = b" ".join(fields)[:80].decode("ascii", "replace")
            want = f"expected 8 numbers '{' '.join(COLUMNS)}'"
            return f"{here}: {want}, got {len(fields)} fields: {text!r}"
        for name, tok in zip(COLUMNS, fields, strict=True):
            try:
                value = float(tok) if b"_" not in tok else None
            except ValueError:
                value = None
            text = tok.decode("ascii", "replace")
            if value is None:
                return f"{here}: {name} {text!r} is not a number"
            if name == "timestamp" and not abs(value) < MAX_STAMP_S:
                return f"{here}: timestamp {text!r} is not a finite time in seconds (|t| < 9.2e9)"
            if not np.isfinite(value):
                return f"{here}: {name} {text!r} is not a finite number"
    return ""


def _parse(data: bytes, path: Path) -> tuple[F64, F64, F64]:
    """Stamps (N,) in s, positions (N, 3) and quaternions (N, 4) of checked TUM text, by
    numpy's C text reader (the one KITTI and EuRoC go through): every value is the double
    ``float()`` gives, and numpy is loaded already (pandas' import cost a compare 0.2-0.3 s)."""
    import warnings

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # "input contained no data": refused below
            table = np.loadtxt(io.BytesIO(data), comments="#", dtype=np.float64, ndmin=2)
    except ValueError as exc:  # a field that is no number, a line of another width
        bad = _first_bad_line(data) or f"cannot parse: {' '.join(str(exc).split())}"
        raise LogReadError(f"{path}: {bad}") from None
    if table.shape[0] == 0:
        raise LogReadError(f"{path}: no poses (empty TUM file)")
    if table.shape[1] != 8:
        raise LogReadError(f"{path}: {_first_bad_line(data) or 'not 8 columns'}")
    stamps = table[:, 0]
    if not np.isfinite(table.min() + table.max()) or np.abs(stamps).max() >= MAX_STAMP_S:
        raise LogReadError(f"{path}: {_first_bad_line(data)}")  # NaN, inf, far stamps
    return stamps, table[:, 1:4], table[:, 4:8]


def read_tum(path: str | Path, *, frame: str = "enu", topic: str = "") -> PoseStream:
    """Read a TUM trajectory file into a :class:`PoseStream` (stamps in ns, frame ``frame``).

    Unsorted or duplicate stamps and slightly non-unit quaternions are repaired and counted in
    ``stream.repairs``; anything else wrong raises :class:`LogReadError` naming the file, the
    line and what is wrong.
    """
    p = Path(path)
    if not p.exists():
        raise LogReadError(f"{p}: no such file or directory")
    try:
        data = p.read_bytes()
    except OSError as exc:
        raise LogReadError(f"{p}: cannot read: {exc}") from exc
    if not data:
        raise LogReadError(f"{p}: file is empty")
    if data.startswith(b"\xef\xbb\xbf"):  # a UTF-8 BOM (Windows tools): blank, offsets kept
        data = b"   " + data[3:]
    off = _stray_byte(data)
    if off >= 0:
        line = data.count(b"\n", 0, off) + 1
        what = f"byte 0x{data[off]:02X}{_BYTE_NAMES.get(data[off], '')}"
        what = "a carriage return inside the line" if data[off] == 0x0D else what
        raise LogReadError(
            f"{p}: line {line} (byte offset {off}): {what}: refused (TUM fields are "
            "separated by spaces or tabs; a line ends in LF or CRLF)"
        )
    stamps, position, quat = _parse(data, p)
    norms = np.sqrt(np.einsum("ij,ij->i", quat, quat))
    off_unit = np.abs(norms - 1.0) > QUAT_NORM_TOLERANCE
    if off_unit.any():
        k = int(np.argmax(off_unit))
        here = next(h for i, (h, _) in enumerate(data_lines(data)) if i == k)
        raise LogReadError(
            f"{p}: {here}: quaternion qx qy qz qw has norm {norms[k]:.6g}, more than "
            f"{QUAT_NORM_TOLERANCE} from 1: refused (is it x, y, z, w order?)"
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
    """Write ``stream`` as a TUM file (stamps in seconds with 9 decimals: exact ns), poses
    as they are stored (in the stream's own frame convention)."""
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
