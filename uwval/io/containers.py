"""Container readers: a :class:`RawLog` of an MCAP file (:mod:`uwval.io.mcap_raw`), a ROS 1
bag (:mod:`uwval.io.bag1_raw`), a rosbag2 directory (``metadata.yaml`` through ruamel.yaml;
sqlite3 or MCAP storage, split files, zstd file or message compression) or a bare ``.db3``.

sqlite3 storage is read with Python's sqlite3 and trusted no further than it is checked:
rows in table order (not through the timestamp index, whose damage sqlite's quick_check
misses), ordered by their own timestamps; rows of wrong column types named and skipped; one
topic under several ids or spellings read whole and said so.
"""

from __future__ import annotations

import contextlib
import sqlite3
from collections.abc import Iterable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from operator import itemgetter
from pathlib import Path
from typing import Any

import numpy as np

from uwval.errors import LogReadError
from uwval.io.formats import log_kind
from uwval.io.raw import (
    I64,
    RawLog,
    RawTopic,
    TopicBuilder,
    TopicInfo,
    load_yaml,
    merge_infos,
    merge_topics,
    norm_topic,
    one_line,
)
from uwval.io.ros import normalize_type_name


def scan_log(path: Path, topics: Iterable[str] | None, *, times_only: bool = False) -> RawLog:
    """Raw messages of ``topics`` (``None``: all) and the list of topics of a ROS log.

    ``times_only``: the selected topics' log times alone (no payloads), for listings."""
    kind, want = log_kind(path), None if topics is None else list(topics)
    if path.is_file() and path.stat().st_size == 0:
        raise LogReadError(f"{path}: file is empty (0 bytes)")
    if kind not in ("mcap", "bag", "db3", "rosbag2"):
        raise LogReadError(f"{path}: not a ROS log ({kind}); read it with read_stream instead")
    try:
        if kind == "mcap":
            from uwval.io.mcap_raw import scan_mcap

            return scan_mcap(path, want, times_only=times_only)
        if kind == "bag":
            from uwval.io.bag1_raw import scan_bag1

            return scan_bag1(path, want, times_only=times_only)
        if kind == "db3":
            return scan_db3(path, path, want, times_only=times_only, zstd_rows=False)
        return _scan_rosbag2(path.parent if path.is_file() else path, want, times_only)
    except LogReadError:
        raise
    except MemoryError as exc:
        raise LogReadError(f"{path}: damaged {kind} log: a size asks for too much memory") from exc
    except Exception as exc:  # damage the format checks did not foresee: still one line
        raise LogReadError(
            f"{path}: damaged {kind} log: {type(exc).__name__}: {one_line(exc)}"
        ) from exc


# ---------------------------------------------------------------- rosbag2 directory
def _metadata(bagdir: Path) -> dict[str, Any] | None:
    """``rosbag2_bagfile_information`` of the bag's metadata.yaml; None when there is none."""
    meta = bagdir / "metadata.yaml"
    if not meta.exists():
        return None
    try:
        info = load_yaml(meta.read_text())["rosbag2_bagfile_information"]
    except Exception as exc:
        raise LogReadError(f"{meta}: not a rosbag2 metadata file: {one_line(exc)}") from exc
    if not isinstance(info, dict):
        raise LogReadError(f"{meta}: rosbag2_bagfile_information is not a mapping")
    return info


def _storage_files(bagdir: Path, info: dict[str, Any] | None) -> list[Path]:
    """The storage files metadata.yaml lists (checked to lie inside the bag directory), or
    without metadata every .mcap and .db3 file of the directory."""
    if info is None:
        return sorted(bagdir.glob("*.mcap")) + sorted(bagdir.glob("*.db3"))
    names = info.get("relative_file_paths") or []
    if not isinstance(names, list):
        raise LogReadError(f"{bagdir / 'metadata.yaml'}: relative_file_paths is not a list")
    for k, f in enumerate(names):
        if not isinstance(f, str) or not f.strip() or f.startswith("/") or ".." in f.split("/"):
            raise LogReadError(
                f"{bagdir / 'metadata.yaml'}: relative_file_paths entry {k} ({f!r}) is not "
                "a file name inside the bag directory"
            )
    return [bagdir / f for f in names]


def _scan_rosbag2(bagdir: Path, topics: list[str] | None, times_only: bool) -> RawLog:
    """Every storage file of a rosbag2 directory, read and joined in file order."""
    info = _metadata(bagdir)
    files = _storage_files(bagdir, info)
    storage = str((info or {}).get("storage_identifier", ""))
    comp_mode = str((info or {}).get("compression_mode", "") or "").upper()
    comp_fmt = str((info or {}).get("compression_format", "") or "")
    missing = [f.name for f in files if not f.exists()]
    compressed = comp_mode in ("FILE", "MESSAGE")
    if comp_mode not in ("", "NONE") and (not compressed or comp_fmt != "zstd"):
        raise LogReadError(f"{bagdir}: unsupported compression {comp_mode!r} {comp_fmt!r}")
    if not files or missing:
        raise LogReadError(f"{bagdir}: storage files missing: {', '.join(missing) or 'all'}")
    import tempfile

    logs: list[RawLog] = []
    unzip = tempfile.TemporaryDirectory(prefix="uwval-rosbag2-") if comp_mode == "FILE" else None
    with unzip or contextlib.nullcontext("") as tmp:  # a folder to decompress into, if need be
        for f in files:
            src = _unzstd(f, Path(tmp)) if comp_mode == "FILE" else f
            if src.stat().st_size == 0:
                raise LogReadError(f"{f}: storage file is empty (0 bytes)")
            if storage == "mcap" or src.suffix == ".mcap":
                from uwval.io.mcap_raw import scan_mcap

                logs.append(scan_mcap(src, topics, times_only=times_only))
            else:
                zstd_rows = comp_mode == "MESSAGE"
                logs.append(scan_db3(f, src, topics, times_only=times_only, zstd_rows=zstd_rows))
    merged = _merge_logs(bagdir, logs)
    if info is None:
        merged.unclean = merged.unclean or "no metadata.yaml: the recorder did not finish"
    else:
        _check_counts(bagdir, info, merged)
    return merged


def _unzstd(src: Path, tmp: Path) -> Path:
    """A zstd-compressed storage file (rosbag2's file compression) decompressed into tmp."""
    import zstandard

    out = tmp / src.name.removesuffix(".zstd")
    try:
        with open(src, "rb") as fi, open(out, "wb") as fo:
            zstandard.ZstdDecompressor().copy_stream(fi, fo)
    except zstandard.ZstdError as exc:
        raise LogReadError(f"{src}: cannot decompress zstd storage file: {one_line(exc)}") from exc
    return out


def _merge_logs(path: Path, logs: list[RawLog]) -> RawLog:
    """One RawLog from the split files of a rosbag2 (topics concatenated in file order)."""
    raw = merge_topics(t for lg in logs for t in lg.raw.values())
    log = RawLog(path, merge_infos(i for lg in logs for i in lg.topics), raw)
    for lg in logs:
        log.lost_bytes += lg.lost_bytes
        log.notes, log.warnings = log.notes + lg.notes, log.warnings + lg.warnings
        log.unclean = log.unclean or lg.unclean
    log.cut_detail = "; ".join(lg.cut_detail for lg in logs if lg.cut_detail)
    return log


def _check_counts(bagdir: Path, info: dict[str, Any], log: RawLog) -> None:
    """Hold metadata.yaml's per-topic message counts against what the storage held: a
    difference is warned; messages listed but absent are counted as ``missing`` drops."""
    listed = info.get("topics_with_message_count")
    if not isinstance(listed, list):
        return
    found = {i.name: i.count for i in log.topics}
    expected: dict[str, int] = {}
    for entry in listed:
        with contextlib.suppress(KeyError, TypeError, ValueError):
            name = norm_topic(str(entry["topic_metadata"]["name"]))
            expected[name] = expected.get(name, 0) + int(entry["message_count"])
    for name, want in expected.items():
        if (got := found.get(name, 0)) != want:
            log.warnings.append(
                f"{bagdir / 'metadata.yaml'}: lists {want} messages on {name}, "
                f"the storage holds {got}"
            )
        if (raw := log.raw.get(name)) is not None and got < want:
            raw.dropped["missing"] = raw.dropped.get("missing", 0) + want - got


# ---------------------------------------------------------------- sqlite3 storage
#: Rows per fetch: a batch's Python objects stay in the CPU caches (~12 % less CPU than 32768)
DB3_BATCH = 1 << 11


def scan_db3(
    name: Path, path: Path, topics: Iterable[str] | None, *, times_only: bool, zstd_rows: bool
) -> RawLog:
    """A rosbag2 sqlite3 storage file ``path`` (reported as ``name``), opened read-only.

    The real path is resolved first (a symlinked .db3 keeps its -wal beside its target); a
    non-empty -wal or -journal (the writer did not finish) is replayed by sqlite on a private
    copy. ``zstd_rows``: each row's data is zstd-compressed."""
    real = path.resolve()
    sides = {s: real.with_name(real.name + s) for s in ("-wal", "-shm", "-journal")}
    pending = [s for s in ("-wal", "-journal") if sides[s].is_file() and sides[s].stat().st_size]
    if not pending:
        uri = real.as_uri() + "?mode=ro&immutable=1"
        return _Db3Reader(name, uri, topics, zstd_rows, times_only).read()
    import shutil
    import tempfile

    with tempfile.TemporaryDirectory(prefix="uwval-db3-") as tmp:
        copy = Path(tmp) / "copy.db3"
        shutil.copyfile(real, copy)
        for suffix, side in sides.items():
            if side.is_file():
                shutil.copyfile(side, copy.with_name(copy.name + suffix))
        log = _Db3Reader(name, copy.as_uri(), topics, zstd_rows, times_only).read()
    left = "write-ahead log" if "-wal" in pending else "rollback journal"
    log.unclean = f"the sqlite {left} was not merged into the file: the writer did not finish"
    return log


#: A row's keys as rosbag2 writes them (data a blob: checked on rows read, typeof loads it)
_KEYS_OK = "typeof(topic_id) = 'integer' AND typeof(timestamp) = 'integer'"
#: A timestamp's 32-bit halves summed (whole stamps would overflow sqlite's int64 SUM)
_HALVES = "SUM(timestamp & 4294967295), SUM(timestamp >> 32)"
_SPAN = "MIN(timestamp), MAX(timestamp)"


@dataclass
class _Db3Reader:
    """One pass over a sqlite3 storage file's messages table (see :func:`scan_db3`)."""

    name: Path
    uri: str
    topics: Iterable[str] | None
    zstd_rows: bool
    times_only: bool
    warnings: list[str] = field(default_factory=list)
    builders: dict[str, TopicBuilder] = field(default_factory=dict)
    topic_of: dict[int, str] = field(default_factory=dict)  # selected topic ids -> name
    sums: I64 = field(default_factory=lambda: np.zeros(3, np.int64))  # rows read, _HALVES
    raw: dict[str, RawTopic] = field(default_factory=dict)  # the topics built

    def read(self) -> RawLog:
        """The storage's topics and the selected topics' messages."""
        try:
            con = sqlite3.connect(self.uri, uri=True)
        except sqlite3.Error as exc:
            raise LogReadError(
                f"{self.name}: cannot open sqlite3 storage: {one_line(exc)}"
            ) from exc
        try:
            tops = self._topics(con)
            # The rows not read are counted per topic on a connection and thread of their
            # own (sqlite releases the GIL) while this one fetches and counts the rest.
            picked = f"topic_id IN ({','.join(map(str, sorted(self.topic_of)))}) AND {_KEYS_OK}"
            picked += "" if self.times_only else " AND typeof(data) = 'blob'"
            with ThreadPoolExecutor(1, thread_name_prefix="uwval-db3-stats") as pool:
                stats = pool.submit(_table_stats, self.uri, f"NOT ({picked})")
                self._fetch(con, picked)  # then the topics built while the stats run on
                self.raw = {n: _time_ordered(b.build()) for n, b in self.builders.items()}
                infos = self._check(con, tops, stats.result())
        except sqlite3.DatabaseError as exc:
            raise LogReadError(f"{self.name}: damaged sqlite3 storage: {one_line(exc)}") from exc
        finally:
            con.close()
        infos += [t.info() for t in self.raw.values()]  # the rows read
        return RawLog(self.name, merge_infos(infos), self.raw, warnings=self.warnings)

    def _topics(self, con: sqlite3.Connection) -> list[tuple[int, str, str]]:
        """(id, normalised name, type) of the topics table; builders for the selected ones.
        One name under several ids or spellings is one topic, with a warning."""
        try:
            rows = con.execute("SELECT id, name, type, serialization_format FROM topics").fetchall()
        except sqlite3.DatabaseError as exc:
            raise LogReadError(f"{self.name}: not a rosbag2 sqlite3 file: {one_line(exc)}") from exc
        want = None if self.topics is None else {norm_topic(t) for t in self.topics}
        spelled: dict[str, list[str]] = {}
        out = []
        for tid, tname, ttype, fmt in rows:
            if not isinstance(tid, int) or not isinstance(tname, str):
                raise LogReadError(f"{self.name}: topics row {tid!r}: id or name of wrong type")
            name, msgtype = norm_topic(tname), normalize_type_name(str(ttype))
            spelled.setdefault(name, []).append(f"id {tid} as {tname!r}")
            out.append((tid, name, msgtype))
            if want is None or name in want:
                self.topic_of[tid] = name
                enc = "cdr" if fmt == "cdr" else str(fmt)
                self.builders.setdefault(name, TopicBuilder(name, msgtype, enc))
        for name, seen in spelled.items():
            if len(seen) > 1:
                self.warnings.append(
                    f"{self.name}: the topics table lists {name} twice or more "
                    f"({', '.join(seen)}): their messages are read as one topic"
                )
        return out

    def _fetch(self, con: sqlite3.Connection, picked: str) -> None:
        """The ``picked`` rows, in table order, into the builders, :data:`DB3_BATCH` at a
        time; their count and :data:`_HALVES` added to ``sums`` (the index check)."""
        if not self.topic_of:
            return
        ids_of = {n: [t for t in self.topic_of if self.topic_of[t] == n] for n in self.builders}
        cur = con.execute(
            f"SELECT topic_id, timestamp, {'NULL' if self.times_only else 'data'} FROM messages "
            f"NOT INDEXED WHERE {picked}"
        )
        while rows := cur.fetchmany(DB3_BATCH):
            n = len(rows)  # itemgetter maps: a third quicker than zip(*rows) and np.array
            tids = np.fromiter(map(itemgetter(0), rows), np.int64, n)
            stamps = np.fromiter(map(itemgetter(1), rows), np.int64, n)
            datas = [] if self.times_only else list(map(itemgetter(2), rows))
            del rows
            if self.zstd_rows:  # rosbag2's message compression: one zstd frame per row
                datas = self._decompress(datas)
            lens = np.fromiter(map(len, datas), np.int64, n) if datas else np.zeros(n, np.int64)
            buf = np.frombuffer(b"".join(datas), dtype=np.uint8)
            del datas
            offs = np.cumsum(lens) - lens
            self.sums += (n, (stamps & 0xFFFFFFFF).sum(), (stamps >> 32).sum())
            for name, ids in ids_of.items():
                pick = np.flatnonzero(tids == ids[0] if len(ids) == 1 else np.isin(tids, ids))
                self.builders[name].add(buf, offs[pick], lens[pick], stamps[pick])

    def _decompress(self, datas: Iterable[bytes]) -> list[bytes]:
        import zstandard

        try:
            return list(map(zstandard.ZstdDecompressor().decompress, datas))
        except zstandard.ZstdError as exc:
            raise LogReadError(f"{self.name}: a message's zstd data is damaged: {exc}") from exc

    def _check(self, con: sqlite3.Connection, tops: list[Any], stats: Any) -> list[TopicInfo]:
        """Count and log-time span per topic id of the rows not read, and a warning for each
        thing found wrong: the timestamp index, topic ids unknown, rows of wrong types."""
        rest, index = stats
        table = self.sums + [sum(int(r[k] or 0) for r in rest) for k in (1, 4, 5)]
        if index is not None and table.tolist() != [int(x or 0) for x in index]:
            self.warnings.append(
                f"{self.name}: the timestamp index disagrees with the messages table "
                "(damaged file): the rows' own timestamps were read"
            )
        known = {tid: (name, ttype) for tid, name, ttype in tops}
        orphans = [(t, n) for t, n, *_ in rest if isinstance(t, int) and t not in known]
        if orphans:
            self.warnings.append(
                f"{self.name}: messages rows name topic ids the topics table lacks ("
                + ", ".join(f"{n} rows of id {t}" for t, n in orphans[:5])
                + "); they were not read"
            )
        # per topic id: rows of wrong key types (selected ids: every row not read)
        bad = {t: int(n if t in self.topic_of else r[-1] or 0) for t, n, *r in rest}
        for tid in self.topic_of.keys() & bad.keys():
            d = self.raw[self.topic_of[tid]].dropped
            d["damaged_row"] = d.get("damaged_row", 0) + bad[tid]
        total = sum(bad.values())
        sel = ",".join(map(str, self.topic_of))
        named = "SELECT id, typeof(topic_id), typeof(timestamp), typeof(data) FROM messages"
        where = f"NOT ({_KEYS_OK}) OR (topic_id IN ({sel}) AND typeof(data) != 'blob') LIMIT 3"
        for rid, *kinds in con.execute(f"{named} WHERE {where}").fetchall() if total else []:
            should = ("integer", "integer", "blob")  # typeof() of each, as rosbag2 writes them
            col, kind, want = next(x for x in zip(_COLUMNS, kinds, should) if x[1] != x[2])  # noqa: B905
            self.warnings.append(
                f"{self.name}: messages row {rid}: {col} is of type {kind}, not {want}; "
                "the row was skipped"
            )
        if total > 3:
            self.warnings.append(f"{self.name}: {total - 3} more rows of wrong types skipped")
        spans = {t: (lo, hi) for t, _, lo, hi, *_ in rest}
        if total:  # text or blob stamps sort above numbers: spans of the numbers alone
            num = "NOT INDEXED WHERE typeof(timestamp) IN ('integer', 'real') GROUP BY topic_id"
            spans = {t: r for t, *r in con.execute(f"SELECT topic_id, {_SPAN} FROM messages {num}")}
        count = {t: n for t, n, *_ in rest}
        return [
            TopicInfo(name, ttype, count.get(t, 0), *(int(x) for x in spans.get(t, (0, 0))))
            for t, (name, ttype) in known.items()
        ]


_COLUMNS = ("topic_id", "timestamp", "data")


def _table_stats(uri: str, where: str) -> tuple[list[Any], Any]:
    """Per topic_id of the messages rows ``where`` holds (own connection): id, count, span,
    :data:`_HALVES`, rows not :data:`_KEYS_OK`; the timestamp index's count and halves or None."""
    con = sqlite3.connect(uri, uri=True)
    try:
        rest = con.execute(
            f"SELECT topic_id, COUNT(*), {_SPAN}, {_HALVES}, SUM(NOT ({_KEYS_OK})) FROM messages "
            f"NOT INDEXED WHERE {where} GROUP BY topic_id"
        ).fetchall()
        has = "SELECT 1 FROM sqlite_master WHERE type = 'index' AND name = 'timestamp_idx'"
        index = f"SELECT COUNT(*), {_HALVES} FROM messages INDEXED BY timestamp_idx"
        return rest, con.execute(index).fetchone() if con.execute(has).fetchone() else None
    finally:
        con.close()


def _time_ordered(topic: RawTopic) -> RawTopic:
    """The topic's messages in log-time order (ties in table order), as rosbag2 plays them."""
    t = topic.log_time
    if t.size > 1 and bool((t[1:] < t[:-1]).any()):
        order = np.argsort(t, kind="stable")
        topic.log_time, topic.offset, topic.length = (
            t[order],
            topic.offset[order],
            topic.length[order],
        )
    return topic
