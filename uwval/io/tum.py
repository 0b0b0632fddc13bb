"""TUM trajectory text files: ``timestamp tx ty tz qx qy qz qw`` per line (evo's format).

The reader is vectorised: the text is parsed in ~1 MB blocks of whole lines by numpy's C
``loadtxt`` reader (no per-line Python loop; bounded text in memory) straight into one
preallocated (N, 8) table; comments, blank lines and malformed lines take a thorough path
that names the bad line. :func:`read_tum_pair` parses two large files concurrently (the
second in a forked child). The stamp column is turned into int64 nanoseconds by an exact
split of each double into whole seconds and fraction, so that converting back with
:func:`seconds_from_ns` gives bit-for-bit the double evo parses (which keeps evo-compatible
stamp association exact). Poses are taken as ENU/FLU unless the caller states another
convention.
"""

from __future__ import annotations

import contextlib
import io
import os
import pickle
import re
import signal
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


_CHUNK = 1 << 20  # bytes parsed per block: bounds the text and temporaries held at once


def parse_tum_file(path: Path) -> NDArray[np.float64]:
    """Parse a TUM file into an (N, 8) float64 table, block by block.

    Only about ``_CHUNK`` bytes of text are held at a time (plain reads: an mmap would count
    the whole file as resident memory) and the table is sized from the first block's bytes
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
        carry = head[start:]
        per_line = max(1.0, len(carry) / max(1, carry.count(b"\n")))
        table = np.empty((int((size - start) / per_line * 1.05) + 16, 8), dtype=np.float64)
        rows = 0
        eof = False
        while not eof:
            more = fh.read(_CHUNK)
            eof = not more
            text = carry + more if more else carry
            if not eof:
                cut = text.rfind(b"\n") + 1
                if cut == 0:  # no newline yet: a very long line, read on
                    carry = text
                    continue
                text, carry = text[:cut], text[cut:]
            elif text and not text.endswith(b"\n"):
                text += b"\n"
            if not text.strip():
                continue
            block = _parse_block(text) if b"#" not in text else None
            if block is None:  # comments, blank lines or bad lines: the thorough path
                fh.seek(0)
                return _parse_whole(fh.read(), str(path))
            k = block.shape[0]
            if rows + k > table.shape[0]:
                table = np.resize(table, (2 * (rows + k), 8))
            table[rows:rows + k] = block
            rows += k
            del block, text
    if rows == 0:
        raise LogReadError(f"{path}: no poses (empty TUM file)")
    return table[:rows]


def _parse_block(text: bytes) -> NDArray[np.float64] | None:
    """Complete lines (no comments) -> (n, 8) table, or None if they are not lines of 8 numbers.

    ``np.loadtxt``'s C reader (numpy >= 1.23) checks the column count per line and converts
    with CPython's correctly rounded strtod: values equal ``float(token)`` bit for bit, and
    it is ~1.4x faster than ``np.fromstring(sep=" ")`` here. None sends the caller to the
    whole-text path, which names the bad line.
    """
    try:
        values = np.loadtxt(io.BytesIO(text), dtype=np.float64, comments=None, ndmin=2,
                            encoding="latin-1", quotechar=None)
    except ValueError:
        return None
    if values.shape[1] != 8:
        return None
    return values


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
    return _stream_from_table(p, _load_table(p), frame, topic)


#: Both files at least this large: parse the second one in a forked child, concurrently.
PARALLEL_MIN_BYTES = 4 << 20


def read_tum_pair(path_a: str | Path, path_b: str | Path, *, frame_a: str = "enu",
                  frame_b: str = "enu", topic_a: str = "", topic_b: str = "",
                  parallel: bool | None = None) -> tuple[PoseStream, PoseStream]:
    """Read two TUM files, as ``(read_tum(path_a, ...), read_tum(path_b, ...))``.

    Parsing text holds the GIL (threads do not help), so for large files (``parallel=None``:
    both >= :data:`PARALLEL_MIN_BYTES`, on systems with ``os.fork``) the second file is parsed
    in a forked child while this process parses the first; the child sends its (N, 8) table
    back through a pipe. Results and errors are the same as reading one after the other
    (the first file's error wins).
    """
    pa, pb = Path(path_a), Path(path_b)
    if parallel is None:
        parallel = hasattr(os, "fork") and all(
            p.is_file() and p.stat().st_size >= PARALLEL_MIN_BYTES for p in (pa, pb))
    if not parallel:
        return (read_tum(pa, frame=frame_a, topic=topic_a),
                read_tum(pb, frame=frame_b, topic=topic_b))
    with _ForkedTable(pb) as pending:
        table_a = _load_table(pa)
        table_b = pending.result()
    return (_stream_from_table(pa, table_a, frame_a, topic_a),
            _stream_from_table(pb, table_b, frame_b, topic_b))


class _ForkedTable:
    """Parse one TUM file in a forked child; ``result()`` returns its table (or re-raises).

    Protocol on the pipe: a pickled header, ``("ok", rows)`` followed by ``rows * 64`` bytes
    of the float64 table, or ``("error", exception)``. Leaving the ``with`` block without
    ``result()`` (the first file failed) kills and reaps the child.
    """

    def __init__(self, path: Path) -> None:
        self.path = path
        self.pid = -1
        self.reader: io.BufferedReader | None = None

    def __enter__(self) -> _ForkedTable:
        read_fd, write_fd = os.pipe()
        pid = os.fork()
        if pid == 0:  # child: parse, send, leave without running the parent's cleanup
            code = 0
            try:
                os.close(read_fd)
                with os.fdopen(write_fd, "wb") as out:
                    try:
                        table = _load_table(self.path)
                    except Exception as exc:  # sent to the parent, re-raised there
                        pickle.dump(("error", exc), out)
                    else:
                        pickle.dump(("ok", table.shape[0]), out)
                        out.write(np.ascontiguousarray(table).data.cast("B"))
            except BaseException:  # the parent sees a short read and reports it
                code = 1
            finally:
                os._exit(code)
        os.close(write_fd)
        self.pid = pid
        self.reader = os.fdopen(read_fd, "rb")
        return self

    def result(self) -> F64:
        assert self.reader is not None
        try:
            kind, payload = pickle.load(self.reader)
        except (EOFError, pickle.UnpicklingError):
            kind, payload = "error", LogReadError(f"{self.path}: the parser process failed")
        if kind == "error":
            raise payload
        table = np.empty((int(payload), 8), dtype=np.float64)
        view = table.data.cast("B")
        got = 0
        while got < view.nbytes:
            n = self.reader.readinto(view[got:])
            if not n:
                raise LogReadError(f"{self.path}: the parser process stopped early")
            got += n
        return table

    def __exit__(self, *exc: object) -> None:
        if self.reader is not None:
            self.reader.close()
        if self.pid > 0:
            if exc[0] is not None:
                with contextlib.suppress(ProcessLookupError):
                    os.kill(self.pid, signal.SIGKILL)
            os.waitpid(self.pid, 0)


def _load_table(p: Path) -> F64:
    """The (N, 8) table of a TUM file, file-system errors as :class:`LogReadError`."""
    if not p.exists():
        raise LogReadError(f"{p}: no such file or directory")
    try:
        return parse_tum_file(p)
    except OSError as exc:
        raise LogReadError(f"{p}: cannot read: {exc}") from exc


def _stream_from_table(p: Path, table: F64, frame: str, topic: str) -> PoseStream:
    """Stamps to ns, then a PoseStream: views of the table when clean, else repaired."""
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
