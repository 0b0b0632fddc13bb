"""Fast path of the rosbag2 sqlite3 reader: the ``messages`` table read from its pages.

Python's sqlite3 module hands out one Python row per message (~0.5 µs each) and the per-topic
counts take a second pass over the table. :func:`read_pages` instead lets the optional C
accelerator ``uwval.io._db3pages`` walk the table's B-tree and rosbag2's timestamp index
straight from the file's bytes (an mmap), one pass, no per-message Python, the selected
payloads copied into one contiguous buffer.

It gives exactly what the sqlite3 path gives (:func:`uwval.io.containers._fetch_db3` and its
``GROUP BY`` statistics), or nothing:

* sqlite3 still answers the small questions: the page size, the root pages of ``messages``
  and of the index, the columns (only rosbag2's schema ``id INTEGER PRIMARY KEY, topic_id
  INTEGER, timestamp INTEGER, data BLOB`` is taken) and the index (one ascending key,
  ``timestamp``, not partial), and the query plan: ``ORDER BY timestamp`` must be answered by
  walking that index, so the order is the index's ((timestamp, rowid) ascending);
* the C scan checks every byte it relies on (see ``_db3pages.c``) and declines on anything
  unexpected (damage, another schema, an index that disagrees with the table).

A decline returns ``None`` and the caller reads the file with sqlite3 as before, which then
reports what is wrong in its own words. Only an immutable file (no write-ahead log to replay)
is read this way; the caller decides that.
"""

from __future__ import annotations

import mmap
import os
import re
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from uwval.io.started import StartedReads

if TYPE_CHECKING:  # numpy loads when a scan's result is converted (uwval.io.early runs first)
    import sqlite3

    import numpy as np
    from numpy.typing import NDArray

    U8 = NDArray[np.uint8]
    I64 = NDArray[np.int64]

try:  # the optional C accelerator (uwval/io/_db3pages.c), built when a compiler is present
    from uwval.io import _db3pages
except ImportError:  # pragma: no cover - the sqlite3 path gives the same result, slower
    _db3pages = None  # type: ignore[assignment]

#: Read pages with the C accelerator when it is built, unless the environment variable
#: ``UWVAL_NO_ACCELERATOR`` is set (benchmarks and tests check both paths). Read at each call.
USE_ACCELERATOR = _db3pages is not None and not os.environ.get("UWVAL_NO_ACCELERATOR")

#: rosbag2's messages table: (column name, declared type, primary-key position), in order.
ROSBAG2_COLUMNS = [
    ("id", "INTEGER", 1),
    ("topic_id", "INTEGER", 0),
    ("timestamp", "INTEGER", 0),
    ("data", "BLOB", 0),
]

_PLAN = re.compile(r"SCAN (?:TABLE )?messages USING INDEX (\S+)")


@dataclass
class Db3Pages:
    """What the page scan read from one .db3 file.

    ``stats`` maps every topic id of the ``topics`` table to (message count, first, last
    log time in ns), as ``GROUP BY topic_id`` gives it ((0, 0, 0) when it has none);
    ``topics`` maps each selected topic id to (payload buffer, offsets, lengths, log times
    in ns): its messages in ``ORDER BY timestamp`` order (ties by rowid).
    """

    stats: dict[int, tuple[int, int, int]]
    topics: dict[int, tuple[U8, I64, I64, I64]]


def index_plan(con: sqlite3.Connection, selected: list[int]) -> tuple[int, int, int] | str:
    """(page size, root page of ``messages``, root page of its timestamp index), checked as
    the module docstring says, or a str naming why the page scan does not apply."""
    tables = con.execute(
        "SELECT rootpage, sql FROM sqlite_master WHERE type = 'table' AND name = 'messages'"
    ).fetchall()
    if len(tables) != 1 or not isinstance(tables[0][0], int):
        return "no single messages table"
    table_root, sql = tables[0]
    if "WITHOUT ROWID" in re.sub(r"\s+", " ", str(sql).upper()):
        return "messages is a WITHOUT ROWID table"
    cols = [
        (str(name), str(ctype).upper(), pk)
        for _cid, name, ctype, _nn, _dflt, pk in con.execute("PRAGMA table_info(messages)")
    ]
    if cols != ROSBAG2_COLUMNS:
        return f"messages has columns {cols}, not rosbag2's"
    ids = selected or [0]
    plan = con.execute(
        "EXPLAIN QUERY PLAN SELECT topic_id, timestamp, data FROM messages WHERE topic_id IN "
        f"({','.join('?' * len(ids))}) ORDER BY timestamp",
        ids,
    ).fetchall()
    m = _PLAN.fullmatch(str(plan[0][3])) if len(plan) == 1 else None
    if m is None:
        return f"sqlite does not walk a timestamp index for ORDER BY timestamp: {plan}"
    index = m.group(1)
    listed = [r for r in con.execute("PRAGMA index_list(messages)") if r[1] == index]
    if len(listed) != 1 or listed[0][4] != 0:
        return f"index {index} is not listed once or is partial"
    xinfo = [tuple(r) for r in con.execute(f'PRAGMA index_xinfo("{index}")')]
    if xinfo != [(0, 2, "timestamp", 0, "BINARY", 1), (1, -1, None, 0, "BINARY", 0)]:
        return f"index {index} is not one ascending key on timestamp: {xinfo}"
    roots = con.execute(
        "SELECT rootpage FROM sqlite_master WHERE type = 'index' AND name = ?", (index,)
    ).fetchall()
    if len(roots) != 1 or not isinstance(roots[0][0], int):
        return f"index {index} has no single root page"
    (page_size,) = con.execute("PRAGMA page_size").fetchone()
    return int(page_size), int(table_root), int(roots[0][0])


def scan_pages(
    path: Path, con: sqlite3.Connection, topic_ids: list[int], selected: list[int]
) -> Db3Pages | str:
    """Read ``path`` (the file ``con`` has open, immutable) from its pages: statistics of
    every id in ``topic_ids`` (the ``topics`` table's), messages of the ids in ``selected``.
    Returns a str naming the reason when the fast path does not apply (see the module
    docstring); sqlite3 errors of the small queries count as such a reason."""
    args = plan_scan(con, topic_ids, selected)
    if isinstance(args, str):
        return args
    got = take_started(path, args)  # a scan begun before the imports (uwval.io.early)
    if got is None:
        try:
            with open(path, "rb") as f, mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) as mm:
                got = run_scan(mm, args)
        except (OSError, ValueError) as exc:
            return f"cannot map the file: {exc}"
    if isinstance(got, str):
        return got
    import numpy as np

    ids = np.frombuffer(args[3], dtype=np.int64)
    group = {tid: k for k, tid in enumerate(sorted(selected))}
    stats_b, counts_b, stamps_b, offs_b, lens_b, payloads = got
    stats = np.frombuffer(stats_b, dtype=np.int64).reshape(-1, 3)
    counts = np.frombuffer(counts_b, dtype=np.int64)
    stamps = np.frombuffer(stamps_b, dtype=np.int64)
    offs = np.frombuffer(offs_b, dtype=np.int64)
    lens = np.frombuffer(lens_b, dtype=np.int64)
    out: dict[int, tuple[U8, I64, I64, I64]] = {}
    row = 0
    for tid, k in group.items():
        n = int(counts[k])
        sl = slice(row, row + n)
        out[tid] = (
            np.frombuffer(memoryview(payloads[k]), dtype=np.uint8),
            offs[sl],
            lens[sl],
            stamps[sl],
        )
        row += n
    return Db3Pages(
        {int(t): (int(s[0]), int(s[1]), int(s[2])) for t, s in zip(ids, stats, strict=True)},
        out,
    )


def plan_scan(
    con: sqlite3.Connection, topic_ids: list[int], selected: list[int]
) -> tuple[int, int, int, bytes, bytes, int] | str:
    """The arguments of :func:`run_scan` for the file ``con`` has open (every id of its
    ``topics`` table in ``topic_ids``, the ids to read in ``selected``), or a str naming why
    the page scan does not apply; sqlite3 errors of the small queries count as such a reason.
    The read (:func:`scan_pages`) and the early start (:mod:`uwval.io.early`) both plan here,
    so that they ask for the same scan."""
    import sqlite3

    if _db3pages is None:
        return "the C accelerator uwval.io._db3pages is not built"
    if not all(isinstance(t, int) for t in topic_ids) or len(set(topic_ids)) != len(topic_ids):
        return "topic ids are not distinct integers"
    if not set(selected) <= set(topic_ids):
        return "a selected topic id is not in the topics table"
    try:
        found = index_plan(con, sorted(selected))
    except sqlite3.DatabaseError as exc:
        return f"sqlite3: {exc}"
    if isinstance(found, str):
        return found
    return scan_args(found, topic_ids, selected)


def has_wal(path: Path) -> bool:
    """Whether the sqlite3 file ``path`` has a non-empty write-ahead log beside it (committed
    pages not in the file yet: the file cannot be read as immutable)."""
    wal = path.with_name(path.name + "-wal")
    return wal.exists() and wal.stat().st_size > 0


def scan_args(
    found: tuple[int, int, int], topic_ids: list[int], selected: list[int]
) -> tuple[int, int, int, bytes, bytes, int]:
    """The arguments of :func:`run_scan` after the map: (page size, table root, index root)
    from :func:`index_plan`, every topic id (ascending, int64) and each one's output group
    (int32: its rank among the ``selected`` ids, -1 when not selected), the group count."""
    page_size, table_root, index_root = found
    ids = sorted(topic_ids)
    group = {tid: k for k, tid in enumerate(sorted(selected))}
    pick = [group.get(int(t), -1) for t in ids]
    return (
        page_size,
        table_root,
        index_root,
        ids_bytes(ids, "q"),
        ids_bytes(pick, "i"),
        len(group),
    )


#: what the page scan returns: (stats, counts, stamps, offsets, lengths, payloads per group),
#: or a str naming why it declines
ScanResult = tuple[bytearray, bytearray, bytearray, bytearray, bytearray, tuple[Any, ...]] | str


def run_scan(mm: Any, args: tuple[int, int, int, bytes, bytes, int]) -> ScanResult:
    """``_db3pages.scan`` of the read-only map ``mm`` with :func:`scan_args`' arguments (its
    pages are dropped from the process as they are read)."""
    assert _db3pages is not None
    page_size, table_root, index_root, ids, pick, ngroups = args
    return _db3pages.scan(mm, page_size, table_root, index_root, ids, pick, ngroups, True)


def ids_bytes(values: list[int], code: str) -> bytes:
    """``values`` as native machine integers (``array`` type ``code``: q int64, i int32), the
    bytes numpy's ``tobytes`` gives for the same values and dtype."""
    from array import array

    return array(code, values).tobytes()


#: scans started and not taken yet, by the file (identity) and arguments they were given
_started: StartedReads[ScanResult] = StartedReads()


def start_scan(path: Path, args: tuple[int, int, int, bytes, bytes, int]) -> None:
    """Run :func:`run_scan` of the file ``path`` with ``args`` on its own thread, for the read
    to take (:func:`take_started`) if it makes exactly this scan (:mod:`uwval.io.early`)."""
    _started.start(path, args, lambda mm: run_scan(mm, args), "uwval-early-db3")


def take_started(path: Path, args: tuple[int, int, int, bytes, bytes, int]) -> ScanResult | None:
    """The result of the scan :func:`start_scan` began of ``path`` (unchanged since) with
    exactly ``args``, waiting for it to end; None when there is none (or it failed). Every
    scan not taken is then dropped: a read happened, they are of no use."""
    return _started.take(path, args)


def read_pages(
    path: Path, con: sqlite3.Connection, topic_ids: list[int], selected: list[int]
) -> Db3Pages | None:
    """:func:`scan_pages`, or ``None`` when it declines or the accelerator is off."""
    if not USE_ACCELERATOR:
        return None
    got = scan_pages(path, con, topic_ids, selected)
    return None if isinstance(got, str) else got
