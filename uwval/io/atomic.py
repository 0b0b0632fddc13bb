"""Write a log so that readers only ever see a complete one, and two writers never mix.

``atomic_output(path)`` yields a temporary path beside ``path`` (same folder, so the final
rename is atomic on one file system). On success the temporary log replaces ``path``; on
failure it is kept as ``<stem>.partial<suffix>`` (what was recorded is not lost, and its name
says it is incomplete). An exclusive ``flock`` on ``.<name>.lock`` stops a second uwval
process from writing the same target at the same time (the lock dies with its process, so a
crash leaves no stale lock that matters).
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import os
import shutil
import stat
from collections.abc import Iterator
from pathlib import Path

from uwval.errors import LogWriteError, UwvalError


def partial_path(path: Path) -> Path:
    """Where an unfinished log of ``path`` is kept: ``run.mcap`` -> ``run.partial.mcap``."""
    return path.with_name(f"{path.stem}.partial{path.suffix}")


def _check_target(path: Path) -> None:
    """Refuse targets that are not a plain file or a rosbag2 folder (devices, FIFOs...)."""
    try:
        st = path.stat()
    except FileNotFoundError:
        return
    except OSError as exc:
        raise LogWriteError(f"{path}: cannot write the log there ({exc.strerror})") from None
    if not (stat.S_ISREG(st.st_mode) or stat.S_ISDIR(st.st_mode)):
        raise LogWriteError(
            f"{path}: not a regular file or folder (a device, FIFO or socket): "
            "write the log to a file"
        )


@contextlib.contextmanager
def _exclusive_lock(path: Path) -> Iterator[None]:
    """Hold an exclusive lock for writing ``path``, or refuse at once if another holds it."""
    lock = path.with_name(f".{path.name}.lock")
    while True:
        try:
            fd = os.open(lock, os.O_RDWR | os.O_CREAT, 0o644)
        except OSError as exc:
            raise LogWriteError(f"{path}: cannot create the lock {lock} ({exc.strerror})") from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as exc:
            os.close(fd)
            if exc.errno in (errno.EAGAIN, errno.EACCES):
                raise LogWriteError(
                    f"{path}: another process is writing this log now (lock {lock}); "
                    "choose another -o or wait for it to finish"
                ) from None
            raise LogWriteError(f"{path}: cannot lock {lock} ({exc.strerror})") from None
        # The holder before us may have removed the lock file after we opened it: then our
        # lock is on a file nobody else sees; take the lock again on the current file.
        try:
            same = os.path.samestat(os.fstat(fd), os.stat(lock))
        except FileNotFoundError:
            same = False
        if same:
            break
        os.close(fd)
    try:
        yield
    finally:
        with contextlib.suppress(OSError):
            os.unlink(lock)
        os.close(fd)


def _remove(path: Path) -> None:
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path)
    elif path.exists() or path.is_symlink():
        path.unlink()


def _with_note(exc: BaseException, note: str) -> BaseException:
    """``exc`` with ``note`` added to its one-line message (uwval errors) or as a note."""
    if isinstance(exc, UwvalError):
        with contextlib.suppress(Exception):
            return type(exc)(f"{exc} ({note})")
    if hasattr(exc, "add_note"):  # Python 3.11+
        exc.add_note(note)
    return exc


@contextlib.contextmanager
def atomic_output(path: str | Path) -> Iterator[Path]:
    """Yield a temporary path to write the log of ``path`` to; publish it when done.

    The temporary path has the same name as ``path`` inside a hidden staging folder beside it
    (so a rosbag2 folder's file names are already final). Raises :class:`LogWriteError` when
    ``path`` is not a regular file or folder, or another process is writing it. The log is
    renamed onto ``path`` only when the body returns; if the body raises, the log recorded so
    far is kept as :func:`partial_path` and the error says so.
    """
    target = Path(path)
    _check_target(target)
    target.parent.mkdir(parents=True, exist_ok=True)
    with _exclusive_lock(target):
        staging = target.with_name(f".{target.name}.writing-{os.getpid()}")
        _remove(staging)
        staging.mkdir()
        tmp = staging / target.name
        try:
            try:
                yield tmp
            except BaseException as exc:
                if not (tmp.exists() or tmp.is_symlink()):
                    raise
                keep = partial_path(target)
                _remove(keep)
                os.replace(tmp, keep)
                noted = _with_note(exc, f"what was recorded is kept in {keep}")
                if noted is exc:
                    raise
                raise noted from exc
            if not tmp.exists():
                return
            if target.is_dir() and not tmp.is_dir():
                raise LogWriteError(f"{target}: a folder is in the way of the log file")
            if target.is_dir():  # a rosbag2 folder: rename cannot replace a non-empty folder
                _remove(target)
            os.replace(tmp, target)
        finally:
            with contextlib.suppress(OSError):
                _remove(staging)
