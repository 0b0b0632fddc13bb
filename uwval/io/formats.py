"""Which format a log is: decided here and only here (by suffix, then by magic bytes).

Kinds: ``mcap``, ``bag`` (ROS 1), ``rosbag2`` (directory or its metadata.yaml), ``db3``
(a bare rosbag2 sqlite3 file), ``csv`` (Unity exports) and ``tum`` (TUM text). Used by the
readers (:mod:`uwval.io.reader`, :mod:`uwval.io.containers`), by ``uwval inspect`` and by
:mod:`uwval.comparison.logs` (``--format``).
"""

from __future__ import annotations

from pathlib import Path

from uwval.errors import ConfigError, LogReadError

#: Suffix -> kind ("rosbag2" only for a file named metadata.yaml).
SUFFIX_KINDS = {
    ".mcap": "mcap",
    ".bag": "bag",
    ".db3": "db3",
    ".csv": "csv",
    ".tum": "tum",
    ".txt": "tum",
    ".yaml": "rosbag2",
}
TUM_SUFFIXES = tuple(s for s, k in SUFFIX_KINDS.items() if k == "tum")
#: Kinds read as text (one stream per file), not as ROS containers.
TEXT_KINDS = ("csv", "tum")
#: Values of ``--format``: ``tum`` selects the TUM text reader; the others name formats the
#: readers recognise by suffix anyway (accepted for clarity, checked for typos).
INPUT_FORMATS = ("tum", "mcap", "bag", "rosbag2", "db3", "csv", "kitti", "euroc")

_MAGIC = ((b"\x89MCAP", "mcap"), (b"#ROSBAG", "bag"), (b"SQLite format 3", "db3"))


def is_tum(path: str | Path, fmt: str | None = None) -> bool:
    """TUM text when ``fmt == 'tum'`` or, with no format given, by suffix .tum/.txt."""
    if fmt is not None:
        if fmt.lower() not in INPUT_FORMATS:
            raise ConfigError(
                f"--format {fmt!r}: choose one of {', '.join(INPUT_FORMATS)} "
                "(default: by the file's suffix)"
            )
        return fmt.lower() == "tum"
    return Path(path).suffix.lower() in TUM_SUFFIXES


def log_kind(path: Path) -> str:
    """``mcap``, ``bag``, ``rosbag2``, ``db3``, ``csv`` or ``tum`` for a log path.

    Refuses (one line) what is missing, or not a regular file or directory (a FIFO with no
    writer would block the reader forever).
    """
    if not path.exists():
        raise LogReadError(f"{path}: no such file or directory")
    if not path.is_dir() and not path.is_file():
        raise LogReadError(
            f"{path}: not a regular file (a FIFO, socket or device); copy the log to a file first"
        )
    if path.is_dir():
        if (path / "metadata.yaml").exists() or any(path.glob("*.mcap")) or any(path.glob("*.db3")):
            return "rosbag2"
        raise LogReadError(f"{path}: directory holds no metadata.yaml, .mcap or .db3 files")
    kind = SUFFIX_KINDS.get(path.suffix.lower())
    if kind is not None:
        if kind == "rosbag2":
            return "rosbag2" if path.name == "metadata.yaml" else "unknown"
        return kind
    with open(path, "rb") as fh:
        head = fh.read(16)
    for magic, k in _MAGIC:
        if head.startswith(magic):
            return k
    raise LogReadError(
        f"{path}: unknown log format (expected .mcap, .bag, .db3, a rosbag2 directory, "
        ".csv or TUM .txt/.tum)"
    )
