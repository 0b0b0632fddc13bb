"""Container readers: return a :class:`RawLog` for the format :func:`log_kind` names.

* ``.mcap`` (ROS 2 or ROS 1 encoded): :mod:`uwval.io.mcap_raw` (fast chunk scanner).
* ``.bag`` (ROS 1): rosbags' rosbag1 reader (uncompressed / bz2 / lz4 chunks, unsorted
  chunks, several connections per topic), payloads gathered into one buffer per topic.
* rosbag2 directory (``metadata.yaml``; sqlite3 or MCAP storage, split files, zstd file or
  message compression) and bare ``.db3``: sqlite read-only (leftover -wal/-shm untouched);
  an immutable uncompressed ``.db3`` is read from its pages by :mod:`uwval.io.db3_pages`
  (the same result; it declines to sqlite on anything unexpected).
"""

from __future__ import annotations

import contextlib
import struct
import threading
from collections.abc import Iterable
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from uwval.errors import LogReadError
from uwval.io.formats import log_kind
from uwval.io.raw import (
    RawLog,
    TopicBuilder,
    TopicInfo,
    merge_infos,
    merge_topics,
    norm_topic,
    one_line,
)
from uwval.io.ros import normalize_type_name

if TYPE_CHECKING:
    import sqlite3


def scan_log(path: Path, topics: Iterable[str] | None, *, times_only: bool = False) -> RawLog:
    """Raw messages of ``topics`` (``None``: all) and the list of topics of a ROS log."""
    kind = log_kind(path)
    if path.is_file() and path.stat().st_size == 0:
        raise LogReadError(f"{path}: file is empty (0 bytes)")
    try:
        return _scan_kind(path, kind, topics, times_only)
    except LogReadError:
        raise
    except MemoryError as exc:
        raise LogReadError(
            f"{path}: damaged {kind} log: a size field asks for too much memory"
        ) from exc
    except Exception as exc:
        # Damaged bytes that the format checks did not anticipate (a library's own exception
        # type, e.g. lz4's RuntimeError): still one line naming the file, never a traceback.
        raise LogReadError(
            f"{path}: damaged {kind} log: {type(exc).__name__}: {one_line(exc)}"
        ) from exc


def _scan_kind(path: Path, kind: str, topics: Iterable[str] | None, times_only: bool) -> RawLog:
    if kind == "mcap":
        from uwval.io.mcap_raw import scan_mcap

        return scan_mcap(path, topics, times_only=times_only)
    if kind == "bag":
        return _scan_bag1(path, topics, times_only)
    if kind == "db3":
        return _scan_db3(path, path, topics, compression="")
    if kind == "rosbag2":
        return _scan_rosbag2(path.parent if path.is_file() else path, topics, times_only)
    raise LogReadError(f"{path}: not a ROS log ({kind}); read it with read_stream instead")


# ---------------------------------------------------------------- ROS 1 bag
def _scan_bag1(path: Path, topics: Iterable[str] | None, times_only: bool) -> RawLog:
    """Fast scanner first; bags it cannot follow go through rosbags (clear error messages)."""
    from uwval.io.bag1_raw import BagFormatError, scan_bag1

    topic_list = None if topics is None else list(topics)
    try:
        return scan_bag1(path, topic_list, times_only=times_only)
    except (BagFormatError, KeyError, IndexError, ValueError, struct.error, OSError) as fast_exc:
        try:
            return _scan_bag1_rosbags(path, topic_list, times_only)
        except LogReadError as exc:
            # The scanner's reason names a byte offset ("record data at byte 13 is cut off");
            # rosbags' ("Header could not be read from file.") does not: say both.
            raise LogReadError(f"{exc} (scanner: {one_line(fast_exc)})") from exc


def _scan_bag1_rosbags(path: Path, topics: Iterable[str] | None, times_only: bool) -> RawLog:
    from rosbags.rosbag1 import Reader, ReaderError

    want = None if topics is None else {norm_topic(t) for t in topics}
    try:
        reader = Reader(path)
        reader.open()
    except ReaderError as exc:
        raise LogReadError(f"{path}: cannot read ROS 1 bag: {one_line(exc)}") from exc
    except Exception as exc:  # rosbags asserts on some damaged index data
        raise LogReadError(
            f"{path}: cannot read ROS 1 bag: damaged index data ({type(exc).__name__}: "
            f"{one_line(exc)})"
        ) from exc
    try:
        builders: dict[str, TopicBuilder] = {}
        times: dict[str, list[int]] = {}
        types: dict[str, str] = {}
        conns = []
        for conn in reader.connections:
            name = norm_topic(conn.topic)
            types.setdefault(name, normalize_type_name(conn.msgtype))
            idx = reader.indexes.get(conn.id, [])
            times.setdefault(name, []).extend(x.time for x in idx)
            if want is None or name in want:
                conns.append(conn)
                if name not in builders:
                    builders[name] = TopicBuilder(
                        name, normalize_type_name(conn.msgtype), "ros1", conn.msgdef.data
                    )
        if conns and not times_only:
            payloads: dict[str, list[bytes]] = {n: [] for n in builders}
            stamps: dict[str, list[int]] = {n: [] for n in builders}
            for conn, timestamp, data in reader.messages(connections=conns):
                name = norm_topic(conn.topic)
                payloads[name].append(data)
                stamps[name].append(timestamp)
            for name, b in builders.items():
                b.add_payloads(payloads[name], stamps[name])
        elif times_only:
            for name, b in builders.items():
                t = np.asarray(times[name], dtype=np.int64)
                b.add(np.zeros(0, np.uint8), np.zeros_like(t), np.zeros_like(t), t)
    except LogReadError:
        raise
    except Exception as exc:
        raise LogReadError(f"{path}: damaged ROS 1 bag: {one_line(exc)}") from exc
    finally:
        reader.close()
    infos = [
        TopicInfo(n, types[n], len(t), min(t) if t else 0, max(t) if t else 0)
        for n, t in times.items()
    ]
    log = RawLog(path, infos, {n: b.build() for n, b in builders.items()})
    if not infos:
        log.notes.append("bag has no connections and no messages")
    return log


# ---------------------------------------------------------------- rosbag2 / sqlite3
def _metadata(bagdir: Path) -> dict[str, Any] | None:
    meta = bagdir / "metadata.yaml"
    if not meta.exists():
        return None
    from uwval.io.bagmeta import load_metadata  # rosbag2 only

    try:
        doc = load_metadata(meta.read_text())
        info = doc["rosbag2_bagfile_information"]
    except Exception as exc:
        raise LogReadError(f"{meta}: not a rosbag2 metadata file: {one_line(exc)}") from exc
    if not isinstance(info, dict):
        raise LogReadError(f"{meta}: rosbag2_bagfile_information is not a mapping")
    return info


def _scan_rosbag2(bagdir: Path, topics: Iterable[str] | None, times_only: bool) -> RawLog:
    info = _metadata(bagdir)
    topic_list = list(topics) if topics is not None else None
    if info is None:
        files = sorted(bagdir.glob("*.mcap")) + sorted(bagdir.glob("*.db3"))
        storage, comp_mode, comp_fmt = "", "", ""
    else:
        names = info.get("relative_file_paths") or []
        if not isinstance(names, list):
            raise LogReadError(f"{bagdir / 'metadata.yaml'}: relative_file_paths is not a list")
        for k, f in enumerate(names):
            if not isinstance(f, str) or not f.strip() or f.startswith("/") or ".." in f.split("/"):
                raise LogReadError(
                    f"{bagdir / 'metadata.yaml'}: relative_file_paths entry {k} ({f!r}) is not "
                    "a file name inside the bag directory"
                )
        files = [bagdir / f for f in names]
        storage = str(info.get("storage_identifier", ""))
        comp_mode = str(info.get("compression_mode", "") or "").upper()
        comp_fmt = str(info.get("compression_format", "") or "")
    if not files:
        raise LogReadError(f"{bagdir}: rosbag2 directory lists no storage files")
    missing = [f.name for f in files if not f.exists()]
    if missing:
        raise LogReadError(f"{bagdir}: storage files missing: {', '.join(missing)}")
    logs: list[RawLog] = []
    with contextlib.ExitStack() as stack:
        tmp: Path | None = None  # made for the first compressed file only
        for f in files:
            src = f
            if comp_mode == "FILE":
                if comp_fmt != "zstd":
                    raise LogReadError(f"{bagdir}: unsupported compression {comp_fmt!r}")
                if tmp is None:
                    import tempfile

                    tmp = Path(
                        stack.enter_context(tempfile.TemporaryDirectory(prefix="uwval-rosbag2-"))
                    )
                src = _unzstd(f, tmp)
            if src.stat().st_size == 0:
                raise LogReadError(f"{f}: storage file is empty (0 bytes)")
            is_mcap = storage == "mcap" or src.suffix == ".mcap"
            if is_mcap:
                from uwval.io.mcap_raw import scan_mcap

                log = scan_mcap(src, topic_list, times_only=times_only)
            else:
                log = _scan_db3(
                    f, src, topic_list, compression=comp_fmt if comp_mode == "MESSAGE" else ""
                )
            logs.append(log)
    merged = _merge_logs(bagdir, logs)
    if info is None:
        merged.unclean = merged.unclean or "no metadata.yaml: the recorder did not finish"
    else:
        _check_counts(bagdir, info, merged)
    return merged


def _unzstd(src: Path, tmp: Path) -> Path:
    import zstandard

    out = tmp / src.name.removesuffix(".zstd")
    try:
        with open(src, "rb") as fi, open(out, "wb") as fo:
            zstandard.ZstdDecompressor().copy_stream(fi, fo)
    except zstandard.ZstdError as exc:
        raise LogReadError(f"{src}: cannot decompress zstd storage file: {one_line(exc)}") from exc
    return out


def _scan_db3(name: Path, path: Path, topics: Iterable[str] | None, compression: str) -> RawLog:
    """A rosbag2 sqlite3 storage file, opened read-only and immutable (no -wal replay)."""
    from uwval.io.db3_pages import has_wal

    want = None if topics is None else {norm_topic(t) for t in topics}
    wal = path.with_name(path.name + "-wal")
    if has_wal(path):
        # Committed pages still in the write-ahead log (writer never closed): read a private
        # copy so sqlite can replay the log without touching the original files.
        import shutil
        import tempfile

        with tempfile.TemporaryDirectory(prefix="uwval-wal-") as tmp:
            for src in (path, wal, path.with_name(path.name + "-shm")):
                if src.exists():
                    shutil.copy(src, Path(tmp) / src.name.replace(path.name, "copy.db3"))
            log = _query_db3(name, f"file:{Path(tmp) / 'copy.db3'}", want, compression)
            log.unclean = (
                "the sqlite write-ahead log was not checkpointed: the writer did not finish"
            )
            return log
    return _query_db3(name, f"file:{path}?mode=ro&immutable=1", want, compression, pages=path)


def _query_db3(
    name: Path, uri: str, want: set[str] | None, compression: str, pages: Path | None = None
) -> RawLog:
    """Read the sqlite3 storage at ``uri``. ``pages``: the same file, immutable (no
    write-ahead log to replay), which :mod:`uwval.io.db3_pages` may then read from its pages
    (the same result, ~10x faster; it declines on anything unexpected and this function
    reads with sqlite3 as before)."""
    import sqlite3  # only rosbag2 sqlite3 logs need it

    try:
        con = sqlite3.connect(uri, uri=True)
    except sqlite3.Error as exc:
        raise LogReadError(f"{name}: cannot open sqlite3 storage: {one_line(exc)}") from exc
    try:
        try:
            rows = con.execute("SELECT id, name, type, serialization_format FROM topics")
            tops = rows.fetchall()
        except sqlite3.DatabaseError as exc:
            raise LogReadError(f"{name}: not a rosbag2 sqlite3 file: {one_line(exc)}") from exc
        builders: dict[int, TopicBuilder] = {}
        for tid, tname, ttype, fmt in tops:
            n = norm_topic(tname)
            if want is not None and n not in want:
                continue
            builders[tid] = TopicBuilder(
                n, normalize_type_name(ttype), "cdr" if fmt == "cdr" else fmt
            )
        fast = None
        if pages is not None and not compression:
            from uwval.io.db3_pages import read_pages

            fast = read_pages(pages, con, [t[0] for t in tops], sorted(builders))
        if fast is not None:  # the messages table read from its pages, statistics included
            for tid, (buf, offs, lens, stamps) in fast.topics.items():
                builders[tid].add(buf, offs, lens, stamps, copy=False)
            stats = fast.stats
        else:
            # Every topic's count and span is one more pass over the table: sqlite runs it
            # on its own connection and thread (it releases the GIL) while this one fetches.
            stats_job = _db3_stats(uri)
            try:
                _fetch_db3(con, name, builders, compression)
            finally:
                stats_job.join()
            if isinstance(stats_job.result, BaseException):
                raise stats_job.result
            stats = stats_job.result
        infos = []
        for tid, tname, ttype, _fmt in tops:
            cnt, lo, hi = stats.get(tid, (0, 0, 0))
            infos.append(
                TopicInfo(norm_topic(tname), normalize_type_name(ttype), int(cnt), int(lo), int(hi))
            )
        raw = {b.name: b.build() for b in builders.values()}
    except sqlite3.DatabaseError as exc:
        raise LogReadError(f"{name}: damaged sqlite3 storage: {one_line(exc)}") from exc
    finally:
        con.close()
    return RawLog(name, infos, raw)


class _StatsJob(threading.Thread):
    """``SELECT topic_id, COUNT(*), MIN(timestamp), MAX(timestamp) ... GROUP BY topic_id`` on
    a connection of its own; ``result`` is {topic id: (count, min, max)} or the exception."""

    def __init__(self, uri: str) -> None:
        super().__init__(name="uwval-db3-stats", daemon=True)
        self.uri = uri
        self.result: dict[int, tuple[int, int, int]] | BaseException = {}

    def run(self) -> None:
        import sqlite3

        try:
            con = sqlite3.connect(self.uri, uri=True)
            try:
                rows = con.execute(
                    "SELECT topic_id, COUNT(*), MIN(timestamp), MAX(timestamp) FROM messages "
                    "GROUP BY topic_id"
                ).fetchall()
            finally:
                con.close()
            self.result = {tid: (cnt, lo, hi) for tid, cnt, lo, hi in rows}
        except BaseException as exc:  # handed to the reading thread, which raises it
            self.result = exc


def _db3_stats(uri: str) -> _StatsJob:
    job = _StatsJob(uri)
    job.start()
    return job


#: Rows fetched from sqlite per step: bounds the Python objects alive at once (~4 MB).
DB3_BATCH = 1 << 14


def _fetch_db3(
    con: sqlite3.Connection, name: Path, builders: dict[int, TopicBuilder], compression: str
) -> None:
    """Every selected topic's messages in one query (``WHERE topic_id IN (...) ORDER BY
    timestamp``: one walk of rosbag2's timestamp index for all of them, not one per topic),
    fetched :data:`DB3_BATCH` rows at a time and split per topic keeping that order (the
    order a per-topic query gives)."""
    if not builders:
        return
    ids = sorted(builders)
    cur = con.execute(
        "SELECT topic_id, timestamp, data FROM messages WHERE topic_id IN "
        f"({','.join('?' * len(ids))}) ORDER BY timestamp",
        ids,
    )
    while rows := cur.fetchmany(DB3_BATCH):
        tids_t, stamps_t, datas_t = zip(*rows, strict=True)
        del rows
        datas = list(datas_t)
        del datas_t
        if compression:
            datas = _decompress_messages(name, compression, datas)
        tids = np.array(tids_t, dtype=np.int64)
        stamps = np.array(stamps_t, dtype=np.int64)
        lens = np.fromiter(map(len, datas), dtype=np.int64, count=len(datas))
        offs = np.zeros_like(lens)
        np.cumsum(lens[:-1], out=offs[1:])
        buf = np.frombuffer(b"".join(datas), dtype=np.uint8)
        del datas
        for tid in ids:
            sel = np.flatnonzero(tids == tid) if len(ids) > 1 else np.arange(len(tids))
            if sel.size:
                builders[tid].add(buf, offs[sel], lens[sel], stamps[sel])


def _decompress_messages(name: Path, fmt: str, datas: list[bytes]) -> list[bytes]:
    if fmt != "zstd":
        raise LogReadError(f"{name}: unsupported message compression {fmt!r}")
    import zstandard

    d = zstandard.ZstdDecompressor()
    return [d.decompress(x) for x in datas]


def _merge_logs(path: Path, logs: list[RawLog]) -> RawLog:
    """One RawLog from the split files of a rosbag2 (topics concatenated in file order)."""
    return RawLog(
        path,
        merge_infos(i for lg in logs for i in lg.topics),
        merge_topics(t for lg in logs for t in lg.raw.values()),
        sum(lg.lost_bytes for lg in logs),
        [x for lg in logs for x in lg.notes],
        [x for lg in logs for x in lg.warnings],
        next((lg.unclean for lg in logs if lg.unclean), ""),
        "; ".join(lg.cut_detail for lg in logs if lg.cut_detail),
    )


def _check_counts(bagdir: Path, info: dict[str, Any], log: RawLog) -> None:
    """Cross-check metadata.yaml's per-topic message counts with what the storage held."""
    listed = info.get("topics_with_message_count")
    if not isinstance(listed, list):
        return
    found = {i.name: i.count for i in log.topics}
    for entry in listed:
        try:
            name = norm_topic(str(entry["topic_metadata"]["name"]))
            expected = int(entry["message_count"])
        except (KeyError, TypeError, ValueError):
            continue
        got = found.get(name, 0)
        if got < expected:
            log.warnings.append(
                f"{bagdir / 'metadata.yaml'}: lists {expected} messages on {name}, "
                f"the storage holds {got}"
            )
            raw = log.raw.get(name)
            if raw is not None:
                raw.dropped["missing"] = raw.dropped.get("missing", 0) + expected - got
