"""Start reading a log on another thread while ``uwval compare`` is still loading its modules.

Loading numpy and the comparison code takes ~60 ms of a ~150 ms compare, on one CPU. A
rosbag2 sqlite3 bag's messages table is read by a call into C that releases the GIL
(:mod:`uwval.io.db3_pages`, ~40 ms for 15 minutes of a simulation's topics), and
:func:`start` begins it on a second thread, before the heavy imports, so that the two
overlap; the read takes the result (``db3_pages.take_started``) only when it makes exactly
the same call (the same file, unchanged, the same topics, pages and roots).
Any other read ignores what was started and reads as it always does. Nothing here imports
numpy.

Only what can be decided cheaply and surely is started: a bag whose ``metadata.yaml`` is in
the usual form (:mod:`uwval.io.bagmeta`), one uncompressed ``.db3`` file, no write-ahead log;
the C accelerator built, a second CPU free. Anything else, or any error, starts nothing.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path


def start(path: Path, topics: Sequence[str]) -> None:
    """Begin reading the log ``path`` for the pose ``topics`` (as :func:`read_streams` will
    be asked for them) on another thread, when that can be done now (see the module
    docstring); otherwise do nothing."""
    try:
        path = Path(path)
        got = _bag_file(path) if path.is_dir() else None
        if got is not None and got[0] == "sqlite3" and got[1].suffix == ".db3":
            _start_db3(got[1], topics)
    except Exception:  # nothing started: the read happens as it always does
        return


def _bag_file(bag: Path) -> tuple[str, Path] | None:
    """(storage, the one file) of a rosbag2 bag whose metadata.yaml is in the usual form and
    lists one uncompressed storage file; None for anything else."""
    from uwval.io.bagmeta import parse_block_yaml

    meta = bag / "metadata.yaml"
    doc = parse_block_yaml(meta.read_text()) if meta.is_file() else None
    info = doc.get("rosbag2_bagfile_information") if doc else None
    if not isinstance(info, dict):
        return None
    files = info.get("relative_file_paths")
    if not (isinstance(files, list) and len(files) == 1 and isinstance(files[0], str)):
        return None
    name = files[0]
    if "/" in name or str(info.get("compression_mode", "") or ""):
        return None
    file = bag / name
    return (str(info.get("storage_identifier", "")), file) if file.is_file() else None


def _start_db3(db3: Path, topics: Sequence[str]) -> None:
    from uwval.cpus import second_cpu_free
    from uwval.io import db3_pages
    from uwval.io.names import norm_topic, topics_to_scan

    if not db3_pages.USE_ACCELERATOR or not second_cpu_free() or db3_pages.has_wal(db3):
        return
    import sqlite3

    want = topics_to_scan(topics)
    con = sqlite3.connect(f"file:{db3}?mode=ro&immutable=1", uri=True)
    try:
        tops = con.execute("SELECT id, name FROM topics").fetchall()
        selected = [tid for tid, tname in tops if norm_topic(str(tname)) in want]
        args = db3_pages.plan_scan(con, [t[0] for t in tops], selected)
    finally:
        con.close()
    if not isinstance(args, str):
        db3_pages.start_scan(db3, args)
