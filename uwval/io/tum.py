"""TUM trajectory text files: ``timestamp tx ty tz qx qy qz qw`` per line (evo's format).

The reader is vectorised: the text is parsed in 256 KiB blocks of whole lines (no per-line
Python loop; bounded text in memory) straight into preallocated arrays, by the optional C
accelerator ``uwval.io._tumparse`` (exact: the same doubles as ``float()``, ~2.5x faster)
or else by numpy's C ``loadtxt`` reader; comments, blank lines and malformed lines take a
thorough path that names the bad line. :func:`read_tum_pair` parses two large files
concurrently (a thread with the accelerator, else a forked child). The stamp column is turned
into int64 nanoseconds by an exact split of each double into whole seconds and fraction, so
that converting back with :func:`seconds_from_ns` gives bit-for-bit the double evo parses
(which keeps evo-compatible stamp association exact). Poses are taken as ENU/FLU unless the
caller states another convention.

Size: one module on purpose: the block parser, the accelerated path, the forked/threaded pair
reader and the thorough error path must agree on one text grammar, so they are kept together.
"""

from __future__ import annotations

import contextlib
import io
import mmap
import os
import pickle
import re
import signal
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import BinaryIO

import numpy as np
from numpy.typing import NDArray

from uwval.errors import LogReadError, LogWriteError, PoseStreamError
from uwval.io.formats import TUM_SUFFIXES
from uwval.io.stamps import NS_PER_S, ns_from_seconds, seconds_from_ns
from uwval.posestream import QUAT_NORM_TOLERANCE, PoseStream

__all__ = [
    "TUM_SUFFIXES",
    "ns_from_seconds",
    "parse_tum_file",
    "read_tum",
    "read_tum_pair",
    "seconds_from_ns",
    "write_tum",
]

try:  # the optional C accelerator (uwval/io/_tumparse.c), built when a compiler is present
    from uwval.io import _tumparse
except ImportError:  # pragma: no cover - numpy's loadtxt gives the same numbers, slower
    _tumparse = None  # type: ignore[assignment]

#: Parse with the C accelerator when it is built, unless the environment variable
#: ``UWVAL_NO_ACCELERATOR`` is set (benchmarks and tests check both paths).
USE_ACCELERATOR = _tumparse is not None and not os.environ.get("UWVAL_NO_ACCELERATOR")

F64 = NDArray[np.float64]
I64 = NDArray[np.int64]

_COMMENT = re.compile(rb"(?m)^[ \t]*#[^\n]*(\n|$)")


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


_CHUNK = 1 << 18  # bytes parsed per block: bounds the text and temporaries held at once
_MIN_LINE = 16  # bytes of the shortest pose line "0 0 0 0 0 0 0 0\n": bounds the row count


class _WholeTextNeededError(Exception):
    """A block is not plain lines of 8 numbers: parse the whole text thoroughly instead."""


def _skip_header(head: bytes) -> int:
    """Offset of the first line of ``head`` that is neither blank nor a comment."""
    start = 0
    while start < len(head):
        end = head.find(b"\n", start)
        end = len(head) if end < 0 else end + 1
        if head[start:end].strip()[:1] not in (b"", b"#"):
            break
        start = end
    return start


def _iter_blocks(fh: BinaryIO, carry: bytes) -> Iterator[F64]:
    """(k, 8) tables of consecutive blocks of whole lines, read ``_CHUNK`` bytes at a time.

    Raises :class:`_WholeTextNeededError` at the first block with comments, or that is not lines
    of 8 numbers (the caller then parses the whole text and names the bad line).
    """
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
        if not text.strip():
            continue
        block = _parse_block(text) if b"#" not in text else None
        if block is None:
            raise _WholeTextNeededError
        yield block


def _read_columns(path: Path, out: tuple[I64, F64] | None = None) -> tuple[I64, F64]:
    """Parse a TUM file into stamps (N,) int64 ns and poses (N, 7) ``tx ty tz qx qy qz qw``.

    Blocks are converted straight into the two final arrays (``out`` when given: capacity
    at least ``size // _MIN_LINE + 1`` rows; else sized from the first block's bytes per
    line), so peak memory is about the arrays themselves. Leading comment lines are skipped;
    files with comments further down take the whole-text path. Any line that is not 8
    numbers raises :class:`LogReadError` naming the line and its byte offset.
    """
    with open(path, "rb") as fh:
        size = fh.seek(0, 2)
        if size == 0:
            raise LogReadError(f"{path}: file is empty")
        _refuse_bare_carriage_return(fh, path)
        fh.seek(0)
        head = fh.read(_CHUNK)
        start = _skip_header(head)
        carry = head[start:]
        if out is None:
            per_line = max(1.0, len(carry) / max(1, carry.count(b"\n")))
            cap = int((size - start) / per_line * 1.05) + 16
            t, pose = np.empty(cap, dtype=np.int64), np.empty((cap, 7), dtype=np.float64)
        else:
            t, pose = out
        rows = 0
        try:
            if USE_ACCELERATOR:
                return _fill_accelerated(fh, carry, path, t, pose, out is not None)
            for block in _iter_blocks(fh, carry):
                k = block.shape[0]
                if rows + k > t.shape[0]:  # estimate too small (lines got longer)
                    if out is not None:  # cannot be from the file as it was sized
                        raise LogReadError(f"{path}: the file grew while being read")
                    t = np.concatenate([t[:rows], np.empty(rows + 2 * k, dtype=np.int64)])
                    pose = np.concatenate([pose[:rows], np.empty((rows + 2 * k, 7))])
                t[rows : rows + k] = _stamps_ns(block[:, 0], path, rows)
                pose[rows : rows + k] = block[:, 1:]
                rows += k
        except _WholeTextNeededError:
            fh.seek(0)
            table = _parse_whole(fh.read(), str(path))
            rows = table.shape[0]
            if out is not None and rows > t.shape[0]:
                raise LogReadError(f"{path}: the file grew while being read") from None
            if out is None:
                return _stamps_ns(table[:, 0], path, 0), table[:, 1:]
            t[:rows] = _stamps_ns(table[:, 0], path, 0)
            pose[:rows] = table[:, 1:]
    if rows == 0:
        raise LogReadError(f"{path}: no poses (empty TUM file)")
    return t[:rows], pose[:rows]


def _refuse_bare_carriage_return(fh: io.BufferedReader, path: Path) -> None:
    """Refuse a carriage return that does not end a line (CRLF is fine).

    The parsers take CR as blank space, as Python's ``float``/``split`` do, so a stray CR
    inside a line (a damaged byte: ``-0.5`` becoming ``\r0.5``) would silently change a
    number; numpy's loadtxt (and evo) see a line break there instead. One ``memchr`` over the
    mapped file when there is no CR at all; a vectorised check of every CR otherwise.
    """
    with mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ) as m:
        if m.find(b"\r") < 0:
            return
        b = np.frombuffer(m, dtype=np.uint8)
        cr = np.flatnonzero(b == 13)
        after = np.minimum(cr + 1, b.size - 1)
        bare = cr[(cr + 1 < b.size) & (b[after] != 10)]
        if bare.size:
            off = int(bare[0])
            line = int(np.count_nonzero(b[:off] == 10)) + 1
            del b, cr, after, bare  # release the exported buffer before the map closes
            raise LogReadError(
                f"{path}: line {line} (byte {off}): a carriage return inside the line (a "
                "damaged file, or old Mac line ends): refused, its numbers cannot be trusted"
            )
        del b, cr, after, bare


def _fill_accelerated(
    fh: io.BufferedReader, carry: bytes, path: Path, t: I64, pose: F64, fixed: bool
) -> tuple[I64, F64]:
    """The C parser's loop of :func:`_read_columns`: blocks of text straight into ``t``/``pose``.

    The text is read into one reused buffer (a new 256 KiB object per block would be fresh
    memory from the OS every time: page faults cost as much as parsing). Each block's stamps
    are written as float seconds into ``t``'s own memory and converted to int64 ns in place.
    Grows the arrays when the first block's estimate was too small (``fixed``: they were
    sized from the file's bound, so a shortage means the file grew). Raises
    :class:`_WholeTextNeededError` on comments or a line that is not 8 numbers.
    """
    assert _tumparse is not None
    buf = bytearray(max(_CHUNK, 2 * len(carry)))
    buf[: len(carry)] = carry
    rows, filled, eof, read = 0, len(carry), False, True
    while True:
        if read and not eof:
            if filled == len(buf):  # one line longer than the buffer: make room
                buf.extend(bytes(len(buf)))
            with memoryview(buf) as view:
                got = fh.readinto(view[filled:])
            eof = not got
            filled += got or 0
        read = True
        stamps = t[rows:].view(np.float64)
        try:
            with memoryview(buf) as view:
                k, used = _tumparse.parse_block(view[:filled], stamps, pose[rows:], eof)
        except ValueError as exc:
            if not str(exc).startswith("byte "):  # not about the text: a bug, not bad input
                raise
            raise _WholeTextNeededError from None
        if k:
            t[rows : rows + k] = _stamps_ns(stamps[:k], path, rows)
            rows += k
        if used:  # keep the unparsed tail (part of a line) at the front
            buf[: filled - used] = buf[used:filled]
            filled -= used
        if rows == t.shape[0] and buf[:filled].strip():  # full, and there is more to parse
            if fixed:
                raise LogReadError(f"{path}: the file grew while being read")
            extra = max(rows, 1024)
            t = np.concatenate([t, np.empty(extra, dtype=np.int64)])
            pose = np.concatenate([pose, np.empty((extra, 7))])
            read = False  # parse what the buffer holds before reading more
            continue
        if eof:
            break
    if rows == 0:
        raise LogReadError(f"{path}: no poses (empty TUM file)")
    return t[:rows], pose[:rows]


_MAX_STAMP_S = 9.2e9  # int64 nanoseconds reach 2**63 ns ~ 9.22e9 s (year 2262)


def _stamps_ns(seconds: F64, path: Path, first_row: int) -> I64:
    """Stamps of pose lines ``first_row...`` as int64 ns; NaN/inf/out-of-range is an error."""
    ok = np.abs(seconds) < _MAX_STAMP_S  # False for NaN too
    if not bool(ok.all()):
        k = int(np.flatnonzero(~ok)[0])
        raise LogReadError(
            f"{path}: pose line {first_row + k + 1}: timestamp {seconds[k]!r} "
            "is not a finite time in seconds (|t| < 9.2e9)"
        )
    return ns_from_seconds(seconds)


def parse_tum_file(path: Path) -> NDArray[np.float64]:
    """Parse a TUM file into an (N, 8) float64 table (stamps in seconds as written).

    Same block reader and errors as :func:`read_tum`, which keeps stamps as int64 ns instead.
    """
    with open(path, "rb") as fh:
        head = fh.read(_CHUNK)
        start = _skip_header(head)
        try:
            blocks = list(_iter_blocks(fh, head[start:]))
        except _WholeTextNeededError:
            fh.seek(0)
            return _parse_whole(fh.read(), str(path))
    if not blocks:
        raise LogReadError(f"{path}: no poses (empty TUM file)")
    return np.concatenate(blocks)


def _parse_block(text: bytes) -> NDArray[np.float64] | None:
    """Complete lines (no comments) -> (n, 8) table, or None if they are not lines of 8 numbers.

    ``np.loadtxt``'s C reader (numpy >= 1.23) checks the column count per line and converts
    with CPython's correctly rounded strtod: values equal ``float(token)`` bit for bit, and
    it is ~1.4x faster than ``np.fromstring(sep=" ")`` here. None sends the caller to the
    whole-text path, which names the bad line.
    """
    try:
        values = np.loadtxt(
            io.BytesIO(text),
            dtype=np.float64,
            comments=None,
            ndmin=2,
            encoding="latin-1",
            quotechar=None,
        )
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
    if values.size and not _lines_of_eight(body):  # e.g. a line of 7 next to one of 9
        raise LogReadError(f"{source}: {_first_bad_line(data)}")
    if values.size == 0:
        raise LogReadError(f"{source}: no poses (empty TUM file)")
    return values.reshape(-1, 8)


_SPACE = np.zeros(256, dtype=bool)
_SPACE[list(b" \t\r\n\v\f")] = True


def _lines_of_eight(body: bytes) -> bool:
    """True when every non-blank line of ``body`` (comments removed) holds exactly 8 tokens.

    Vectorised: a token starts at a non-space byte after a space (or at the start); tokens
    are counted per line with one ``bincount``. The per-line loop :func:`_first_bad_line`
    runs only when this is False, to name the line.
    """
    b = np.frombuffer(body, dtype=np.uint8)
    space = _SPACE[b]
    starts = ~space
    starts[1:] &= space[:-1]
    line = np.cumsum(b == 10)
    per_line = np.bincount(line[starts], minlength=int(line[-1]) + 1)
    return bool(((per_line == 0) | (per_line == 8)).all())


def read_tum(path: str | Path, *, frame: str = "enu", topic: str = "") -> PoseStream:
    """Read a TUM trajectory file into a :class:`PoseStream` (stamps in ns, frame ``frame``).

    Unsorted or duplicate stamps and slightly non-unit quaternions are repaired and counted in
    ``stream.repairs``; NaN values and badly non-unit quaternions raise errors naming the file.
    Clean files (the common case) skip the repair pass: positions and orientations stay
    views of one (N, 7) array, so a 360,000-pose file costs 20 MB of poses + 3 MB of stamps.
    """
    p = Path(path)
    return _stream(p, *_load(p), frame, topic)


#: Both files at least this large: parse the second one in a forked child, concurrently.
PARALLEL_MIN_BYTES = 4 << 20


def read_tum_pair(
    path_a: str | Path,
    path_b: str | Path,
    *,
    frame_a: str = "enu",
    frame_b: str = "enu",
    topic_a: str = "",
    topic_b: str = "",
    parallel: bool | None = None,
) -> tuple[PoseStream, PoseStream]:
    """Read two TUM files, as ``(read_tum(path_a, ...), read_tum(path_b, ...))``.

    For large files (``parallel=None``: both >= :data:`PARALLEL_MIN_BYTES`) the second file
    is parsed concurrently with the first: in a thread when the C accelerator is built (it
    releases the GIL), else in a forked child (numpy's loadtxt holds the GIL; only when
    ``os.fork`` exists and no other thread runs in this process), which writes its arrays
    into shared memory (no copy back). Results and errors are the same as reading one after
    the other (the first file's error wins).
    """
    pa, pb = Path(path_a), Path(path_b)
    if parallel is None:
        # fork only a single-threaded process: another thread could hold a lock (an import,
        # a logging handler) that the child would then wait for forever
        can_fork = hasattr(os, "fork") and threading.active_count() == 1
        parallel = (USE_ACCELERATOR or can_fork) and all(
            p.is_file() and p.stat().st_size >= PARALLEL_MIN_BYTES for p in (pa, pb)
        )
    if not parallel:
        return (
            read_tum(pa, frame=frame_a, topic=topic_a),
            read_tum(pb, frame=frame_b, topic=topic_b),
        )
    second: tuple[I64, F64] | Exception
    if USE_ACCELERATOR:  # the C parser releases the GIL: a thread is enough
        first, second = _threaded_pair(pa, pb)
    else:
        with _ForkedParse(pb) as pending:
            first = _load(pa)
            try:
                second = pending.result()
            except Exception as exc:  # raised below, after the first file's own checks
                second = exc
    stream_a = _stream(pa, *first, frame_a, topic_a)  # its errors win, as read one by one
    if isinstance(second, Exception):
        raise second
    return stream_a, _stream(pb, *second, frame_b, topic_b)


def _threaded_pair(pa: Path, pb: Path) -> tuple[tuple[I64, F64], tuple[I64, F64] | Exception]:
    """Load ``pb`` in a thread while this one loads ``pa`` (C parser: no GIL while parsing).

    ``pa``'s error is raised; ``pb``'s is returned, for the caller to raise after its checks
    of ``pa`` (so that errors are those of reading one file after the other).
    """
    box: dict[str, tuple[I64, F64] | Exception] = {}

    def work() -> None:
        try:
            box["result"] = _load(pb)
        except Exception as exc:  # handed to the caller's thread
            box["result"] = exc

    worker = threading.Thread(target=work, name="uwval-tum-parse", daemon=True)
    worker.start()
    try:
        first = _load(pa)
    finally:
        worker.join()
    if "result" not in box:  # the thread died of something that is not an Exception
        return first, LogReadError(f"{pb}: the parser thread failed")
    return first, box["result"]


class _ForkedParse:
    """Parse one TUM file in a forked child into shared memory; ``result()`` collects it.

    The arrays live in an anonymous shared mapping sized for the most rows the file could
    hold (pages the child does not write cost nothing). The pipe carries a pickled
    ``("ok", rows)`` or ``("error", exception)``. Leaving the ``with`` block without
    ``result()`` (the first file failed) kills and reaps the child.
    """

    def __init__(self, path: Path) -> None:
        self.path = path
        self.pid = -1
        self.reader: io.BufferedReader | None = None
        try:
            size = self.path.stat().st_size
        except OSError:  # reported by the child's read, as read_tum would
            size = 0
        cap = size // _MIN_LINE + 2
        self.shared = mmap.mmap(-1, cap * 8 * 8)
        self.t = np.frombuffer(self.shared, dtype=np.int64, count=cap)
        self.pose = np.frombuffer(
            self.shared, dtype=np.float64, count=cap * 7, offset=cap * 8
        ).reshape(cap, 7)

    def __enter__(self) -> _ForkedParse:
        read_fd, write_fd = os.pipe()
        pid = os.fork()
        if pid == 0:  # child: parse, report, leave without running the parent's cleanup
            code = 0
            try:
                os.close(read_fd)
                with os.fdopen(write_fd, "wb") as out:
                    try:
                        t, _ = _load(self.path, (self.t, self.pose))
                    except Exception as exc:  # sent to the parent, re-raised there
                        pickle.dump(("error", exc), out)
                    else:
                        pickle.dump(("ok", t.shape[0]), out)
            except BaseException:  # the parent sees no report and says so
                code = 1
            finally:
                os._exit(code)
        os.close(write_fd)
        self.pid = pid
        self.reader = os.fdopen(read_fd, "rb")
        return self

    def result(self) -> tuple[I64, F64]:
        assert self.reader is not None
        try:
            kind, payload = pickle.load(self.reader)
        except (EOFError, pickle.UnpicklingError):
            kind, payload = "error", LogReadError(f"{self.path}: the parser process failed")
        if kind == "error":
            raise payload
        rows = int(payload)
        return self.t[:rows], self.pose[:rows]

    def __exit__(self, *exc: object) -> None:
        if self.reader is not None:
            self.reader.close()
        if self.pid > 0:
            if exc[0] is not None:
                with contextlib.suppress(ProcessLookupError):
                    os.kill(self.pid, signal.SIGKILL)
            os.waitpid(self.pid, 0)


def _load(p: Path, out: tuple[I64, F64] | None = None) -> tuple[I64, F64]:
    """Stamps and poses of a TUM file, file-system errors as :class:`LogReadError`."""
    if not p.exists():
        raise LogReadError(f"{p}: no such file or directory")
    try:
        return _read_columns(p, out)
    except OSError as exc:
        raise LogReadError(f"{p}: cannot read: {exc}") from exc


def _stream(p: Path, t: I64, pose: F64, frame: str, topic: str) -> PoseStream:
    """A PoseStream of views into ``pose``, repaired when needed.

    Every parse path has already checked that each line holds 8 numbers (the C parser and
    ``loadtxt`` per line, :func:`_parse_whole` by a vectorised token count), so no column can
    be scrambled here. Quaternions rounded to a few decimals (TUM RGB-D ground truths have 4)
    are normalised in place, vectorised, and counted in ``repairs['renormalized']`` as
    :meth:`PoseStream.from_arrays` counts them; only unsorted or duplicate stamps, NaN or badly
    non-unit quaternions go through ``from_arrays`` (which repairs or names the sample).
    """
    pos, quat = pose[:, 0:3], pose[:, 3:7]
    name = topic or "tum"
    renormalized = _normalize_in_place(t, pose, quat)
    if renormalized is not None:
        return PoseStream(
            t=t,
            position=pos,
            orientation=quat,
            frame=frame,
            topic=name,
            source=str(p),
            repairs={"renormalized": renormalized} if renormalized else {},
        )
    try:
        return PoseStream.from_arrays(t, pos, quat, frame=frame, topic=name, source=str(p))
    except PoseStreamError as exc:
        raise PoseStreamError(f"{exc} (TUM file: sample k is on the k-th pose line)") from None


def _normalize_in_place(t: I64, pose: F64, quat: F64) -> int | None:
    """Normalise ``quat`` (a view into ``pose``) in place when that is the only repair needed.

    Returns how many quaternions were more than 1e-9 from unit norm (0: none, nothing
    touched), or None when the data need :meth:`PoseStream.from_arrays` (non-finite values,
    stamps not strictly increasing, a quaternion beyond ``QUAT_NORM_TOLERANCE``). The
    arithmetic is ``from_arrays``'s (every row divided by its ``np.linalg.norm``), so the
    numbers are the same bits as before this fast path existed.
    """
    if not bool(np.isfinite(pose).all()):
        return None
    if t.size > 1 and not bool((np.diff(t) > 0).all()):
        return None
    norm2 = np.einsum("ij,ij->i", quat, quat)
    if quat.shape[0] == 0 or bool(np.abs(norm2 - 1.0).max() <= 2e-9):
        return 0
    norms = np.linalg.norm(quat, axis=1)
    off = np.abs(norms - 1.0)
    if float(off.max()) > QUAT_NORM_TOLERANCE:
        return None  # from_arrays names the sample
    renorm = int((off > 1e-9).sum())
    if renorm:
        quat /= norms[:, None]
    return renorm


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
