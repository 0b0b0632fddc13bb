"""The page reader of rosbag2 sqlite3 storage (uwval.io.db3_pages, C: _db3pages.c).

Every claim is checked against the sqlite3 path on the same file: the same topics, counts and
spans, the same messages in the same order with the same bytes; and where the page reader
declines (damage, another schema, a write-ahead log), the sqlite3 path answers as before.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import sqlite3
import subprocess
import sys
from collections.abc import Iterable
from pathlib import Path

import io_loggen as gen
import numpy as np
import pytest
from accelerators import require_module

import uwval.io.db3_pages as db3_pages
from uwval.errors import LogReadError
from uwval.io.containers import scan_log

require_module(db3_pages._db3pages, "uwval.io._db3pages")

POSE = "geometry_msgs/msg/PoseStamped"

SCHEMA = """
CREATE TABLE schema(schema_version INTEGER PRIMARY KEY, ros_distro TEXT NOT NULL);
CREATE TABLE metadata(id INTEGER PRIMARY KEY, metadata_version INTEGER NOT NULL,
                      metadata TEXT NOT NULL);
CREATE TABLE topics(id INTEGER PRIMARY KEY, name TEXT NOT NULL, type TEXT NOT NULL,
                    serialization_format TEXT NOT NULL, offered_qos_profiles TEXT NOT NULL,
                    type_description_hash TEXT NOT NULL);
CREATE TABLE messages(id INTEGER PRIMARY KEY, topic_id INTEGER NOT NULL,
                      timestamp INTEGER NOT NULL, data BLOB NOT NULL);
CREATE INDEX timestamp_idx ON messages (timestamp ASC);
"""


def write_db3(
    path: Path,
    rows: Iterable[tuple[int, int, bytes]],
    *,
    topics: Iterable[int] = range(4),
    page_size: int = 4096,
    schema: str = SCHEMA,
    reserved: int = 0,
) -> Path:
    """A .db3 in rosbag2's schema written with sqlite3: ``rows`` are (topic id, timestamp ns,
    payload), inserted in that order (rowids 1, 2, ...); topic k is named /t<k>."""
    con = sqlite3.connect(path)
    con.execute(f"PRAGMA page_size = {page_size}")
    if reserved:
        # sqlite3 sets reserved bytes only through the C API (SQLITE_FCNTL_RESERVE_BYTES),
        # which Python lacks; sqlite keeps a file's value, so patch a fresh one-page file:
        # header byte 20, and page 1's cell content area start (empty: the usable size).
        con.execute("CREATE TABLE _x(a)")
        con.execute("DROP TABLE _x")
        con.commit()
        con.execute("VACUUM")
        con.close()
        data = bytearray(path.read_bytes())
        assert len(data) == page_size and data[100] == 0x0D and data[103:105] == b"\0\0"
        data[20] = reserved
        data[105:107] = (page_size - reserved).to_bytes(2, "big")
        path.write_bytes(bytes(data))
        con = sqlite3.connect(path)
    con.executescript(schema)
    con.executemany(
        "INSERT INTO topics VALUES (?, ?, ?, 'cdr', '', '')", [(k, f"/t{k}", POSE) for k in topics]
    )
    con.executemany("INSERT INTO messages (topic_id, timestamp, data) VALUES (?, ?, ?)", rows)
    con.commit()
    con.close()
    return path


def seeded_rows(
    n: int, seed: int, sizes: Iterable[int] = (84,), ntopics: int = 4
) -> list[tuple[int, int, bytes]]:
    """``n`` interleaved rows with seeded topics, near-monotonic timestamps and payloads."""
    rng = np.random.default_rng(seed)
    size_list = list(sizes)
    stamps = 1_700_000_000_000_000_000 + np.cumsum(rng.integers(0, 3_000_000, size=n))
    stamps[rng.random(n) < 0.1] -= 5_000_000  # some out of order (index order != rowid order)
    out = []
    for i in range(n):
        size = size_list[i % len(size_list)]
        out.append((int(rng.integers(0, ntopics)), int(stamps[i]), rng.bytes(size)))
    return out


def outcome(path: Path, topics: list[str] | None, fast: bool) -> tuple:
    """What scan_log reads (a comparable tuple), or the LogReadError's text."""
    saved = db3_pages.USE_ACCELERATOR
    db3_pages.USE_ACCELERATOR = fast
    try:
        log = scan_log(path, topics)
    except LogReadError as exc:
        return ("error", str(exc))
    finally:
        db3_pages.USE_ACCELERATOR = saved
    raw = {
        name: (
            t.msgtype,
            t.encoding,
            t.log_time.tolist(),
            [t.payload(i) for i in range(len(t))],
            t.dropped,
        )
        for name, t in log.raw.items()
    }
    return ("ok", log.topics, raw, log.warnings, log.unclean, log.notes, log.lost_bytes)


def db3_of(path: Path) -> Path:
    return path if path.suffix == ".db3" else sorted(path.glob("*.db3"))[0]


def pages_read(path: Path, topics: list[str] | None = None) -> db3_pages.Db3Pages | str:
    """The page reader's own answer on ``path`` (a .db3 or rosbag2 dir): result or reason."""
    f = db3_of(path)
    con = sqlite3.connect(f"file:{f}?mode=ro&immutable=1", uri=True)
    try:
        tops = con.execute("SELECT id, name FROM topics").fetchall()
        sel = [i for i, n in tops if topics is None or "/" + str(n).strip("/") in topics]
        return db3_pages.scan_pages(f, con, [i for i, _ in tops], sel)
    finally:
        con.close()


def assert_same(path: Path, topics: list[str] | None = None, *, taken: bool = True) -> tuple:
    """The page reader and the sqlite3 path read ``path`` alike; ``taken``: the page reader
    did read it (did not decline)."""
    got = pages_read(path, topics)
    if taken:
        assert not isinstance(got, str), got
    else:
        assert isinstance(got, str)
    fast, slow = outcome(path, topics, True), outcome(path, topics, False)
    assert fast == slow
    return fast


def interior_pages(path: Path) -> tuple[int, int]:
    """(page size, depth of the messages table's B-tree: 1 = the root is a leaf)."""
    data = path.read_bytes()
    con = sqlite3.connect(path)
    (root,) = con.execute("SELECT rootpage FROM sqlite_master WHERE name = 'messages'").fetchone()
    (ps,) = con.execute("PRAGMA page_size").fetchone()
    con.close()
    depth, pg = 1, root
    while data[(pg - 1) * ps] == 0x05:
        depth += 1
        pg = int.from_bytes(data[(pg - 1) * ps + 8 : (pg - 1) * ps + 12], "big")  # right-most
    return ps, depth


# ------------------------------------------------------------------------- same result
def test_rosbags_writer_interleaved_topics_with_overflowing_images(tmp_path: Path) -> None:
    """rosbags' own writer: poses, applied stamps, /tf, a 40 kB image topic (overflow chains
    of ten pages each); every topic and a pose-only selection read alike."""
    bag = gen.write_log(tmp_path / "bag", "rosbag2-sqlite3", seconds=2.0, image_bytes=40_000)
    res = assert_same(bag)
    assert len(res[2]) >= 5 and all(t.count for t in res[1])
    assert max(len(p) for p in res[2][gen.IMAGE][3]) > 40_000
    assert_same(bag, [gen.GAZEBO, gen.UNITY, gen.APPLIED])
    assert_same(bag, ["/not_there"])


def test_uwval_simulate_rosbag2(tmp_path: Path) -> None:
    from cli_runner import run_uwval

    out = tmp_path / "run"
    res = run_uwval("simulate", "-o", out, "--format", "rosbag2", "--duration", "1.5")
    assert res.returncode == 0, res.stderr
    got = assert_same(out, [gen.GAZEBO, gen.UNITY, gen.APPLIED])
    assert len(got[2][gen.GAZEBO][2]) > 50


@pytest.mark.parametrize("page_size", [512, 4096, 65536])
def test_page_sizes_and_multi_page_blobs(tmp_path: Path, page_size: int) -> None:
    """Topic ids 0 and 1 and timestamps 0 and 1 (serial types 8 and 9), blobs from empty to
    1 MB (chains of up to ~2,000 pages), on three page sizes."""
    rows = seeded_rows(300, seed=page_size, sizes=(0, 1, 84, 40_000, 84, 300))
    rows[5] = (1, 0, b"\x01" * 1_000_000)
    rows[6] = (0, 1, b"")
    rows[7] = (1, 1, b"x" * 5000)
    p = write_db3(tmp_path / "a.db3", rows, page_size=page_size)
    assert_same(p)
    assert_same(p, ["/t1"])


def test_integers_of_every_serial_type(tmp_path: Path) -> None:
    """Timestamps and topic ids of every integer size sqlite stores (1, 2, 3, 4, 6, 8 bytes
    and the constants 0 and 1), negative ones included; topic ids past 65535 (looked up by
    binary search, not the table of small ids)."""
    edges = [0, 1, 2, 127, 128, 32767, 32768, 2**23 - 1, 2**23, 2**31 - 1, 2**31, 2**47 - 1]
    edges += [2**47, 2**63 - 1]
    values = sorted({v for e in edges for v in (e, -e - 1)})
    topics = [-(2**63), -5, 0, 1, 70_000, 2**40]
    rng = np.random.default_rng(12)
    rows = [(topics[k % len(topics)], v, rng.bytes(8)) for k, v in enumerate(values * 3)]
    p = write_db3(tmp_path / "ints.db3", rows, topics=topics)
    res = assert_same(p)
    got = sorted(t for name in res[2] for t in res[2][name][2])
    assert got == sorted(values * 3)
    assert {i.name for i in res[1]} == {f"/t{k}" for k in topics}


def test_reserved_bytes_per_page(tmp_path: Path) -> None:
    """Usable size U = page size - reserved bytes (header byte 20) sets where payloads spill."""
    p = write_db3(
        tmp_path / "r.db3",
        seeded_rows(400, 3, sizes=(84, 3000, 20_000)),
        page_size=1024,
        reserved=32,
    )
    assert p.read_bytes()[20] == 32
    assert_same(p)


def test_deep_tree(tmp_path: Path) -> None:
    """Enough rows on 512-byte pages for a table B-tree of 3+ levels (and a deep index)."""
    p = write_db3(tmp_path / "deep.db3", seeded_rows(30_000, 7, sizes=(60,)), page_size=512)
    assert interior_pages(p)[1] >= 3
    assert_same(p, ["/t0", "/t2"])


@pytest.mark.parametrize("vacuum", [False, True])
def test_deleted_rows(tmp_path: Path, vacuum: bool) -> None:
    """Rowids with gaps (found by binary search), free pages left behind or vacuumed away."""
    p = write_db3(tmp_path / "d.db3", seeded_rows(3000, 11, sizes=(84, 5000)))
    con = sqlite3.connect(p)
    con.execute("DELETE FROM messages WHERE id % 3 = 0 OR (id > 1000 AND id < 1500)")
    con.commit()
    if vacuum:
        con.execute("VACUUM")
    con.close()
    assert_same(p)


def test_equal_timestamps_keep_rowid_order(tmp_path: Path) -> None:
    """Ties of timestamp come out in rowid order, as the index holds them, within a topic
    and across topics; rows inserted newest first."""
    rng = np.random.default_rng(5)
    rows = [(int(k % 3), int(1000 - k // 7), rng.bytes(20)) for k in range(2000)]
    p = write_db3(tmp_path / "eq.db3", rows)
    res = assert_same(p)
    t0 = res[2]["/t0"]
    assert t0[2] == sorted(t0[2])
    ids_at = [r for r in rows if r[0] == 0]
    want = [r[2] for r in sorted(ids_at, key=lambda r: r[1])]  # stable: rowid order kept
    assert t0[3] == want


def test_shared_rosbag2_logs(shared_data: Path, tmp_path: Path) -> None:
    """The real rosbag2 sqlite3 logs (ros2 and evo's example), copied first."""
    for rel in ("bags/rosbag2/cdr_test_sqlite3", "bags/evo/tf_example", "bags/rosbag2/empty_bag"):
        dst = tmp_path / Path(rel).name
        shutil.copytree(shared_data / rel, dst)
        assert_same(dst)


# ---------------------------------------------------------------------------- declines
def test_write_ahead_log_is_replayed_by_sqlite(tmp_path: Path) -> None:
    """Rows still in a non-empty -wal (writer killed): the page reader is not asked (the
    main file lacks those rows); sqlite replays the log on a copy, as before."""
    p = tmp_path / "w.db3"
    con = sqlite3.connect(p)
    con.execute("PRAGMA journal_mode = WAL")
    con.execute("PRAGMA wal_autocheckpoint = 0")
    con.executescript(SCHEMA)
    con.execute("INSERT INTO topics VALUES (0, '/t0', ?, 'cdr', '', '')", (POSE,))
    con.executemany(
        "INSERT INTO messages (topic_id, timestamp, data) VALUES (0, ?, ?)",
        [(i, b"m%d" % i) for i in range(50)],
    )
    con.commit()
    saved = tmp_path / "saved"
    saved.mkdir()
    for f in tmp_path.glob("w.db3*"):
        shutil.copy(f, saved / f.name)  # as a killed writer leaves them
    con.close()
    q = saved / "w.db3"
    assert (saved / "w.db3-wal").stat().st_size > 0
    res = outcome(q, None, True)
    assert res == outcome(q, None, False)
    assert len(res[2]["/t0"][2]) == 50 and "write-ahead log" in res[4]
    alone = tmp_path / "alone"
    alone.mkdir()
    shutil.copy(q, alone / "w.db3")  # the main file without its log: not those 50 rows
    res_alone = outcome(alone / "w.db3", None, True)
    assert res_alone[0] == "error" or len(res_alone[2]["/t0"][2]) < 50


@pytest.mark.parametrize(
    "schema",
    [
        SCHEMA.replace("data BLOB NOT NULL", "data BLOB NOT NULL, extra INTEGER"),
        SCHEMA.replace("timestamp INTEGER NOT NULL, data", "data BLOB, timestamp INTEGER"),
        SCHEMA.replace("CREATE INDEX timestamp_idx ON messages (timestamp ASC);", ""),
        SCHEMA.replace("(timestamp ASC)", "(timestamp DESC)"),
        SCHEMA.replace("(timestamp ASC)", "(timestamp, topic_id)"),
        SCHEMA.replace("id INTEGER PRIMARY KEY, topic_id", "id INTEGER, topic_id"),
    ],
    ids=["extra-column", "column-order", "no-index", "desc-index", "two-key-index", "no-alias"],
)
def test_other_schemas_decline(tmp_path: Path, schema: str) -> None:
    if "data BLOB, timestamp" in schema:
        rows = [(r[0], r[2], r[1]) for r in seeded_rows(200, 1)]
        p = tmp_path / "s.db3"
        con = sqlite3.connect(p)
        con.executescript(schema)
        con.executemany(
            "INSERT INTO topics VALUES (?, ?, ?, 'cdr', '', '')",
            [(k, f"/t{k}", POSE) for k in range(4)],
        )
        con.executemany("INSERT INTO messages (topic_id, data, timestamp) VALUES (?, ?, ?)", rows)
        con.commit()
        con.close()
    else:
        p = write_db3(tmp_path / "s.db3", seeded_rows(200, 1), schema=schema)
    assert_same(p, taken=False)


def test_rows_of_other_types_decline(tmp_path: Path) -> None:
    """A text payload, a real timestamp, a NULL topic: sqlite's types, not rosbag2's."""
    for k, row in enumerate([(0, 5, "text"), (0, 5.5, b"x"), (None, 5, b"x")]):
        p = write_db3(
            tmp_path / f"t{k}.db3",
            [*seeded_rows(50, k), row],
            schema=SCHEMA.replace(" NOT NULL", ""),
        )
        assert isinstance(pages_read(p), str)
        assert outcome(p, ["/t1"], True) == outcome(p, ["/t1"], False)


def _page(ps: int, pg: int) -> int:
    return (pg - 1) * ps


def _damaged(tmp_path: Path, name: str, how: str) -> Path:
    p = write_db3(tmp_path / f"{name}.db3", seeded_rows(3000, 2, sizes=(84, 9000)), page_size=1024)
    con = sqlite3.connect(p)
    (root,) = con.execute("SELECT rootpage FROM sqlite_master WHERE name = 'messages'").fetchone()
    con.close()
    data = bytearray(p.read_bytes())
    ps = 1024
    at = _page(ps, root)
    assert data[at] == 0x05
    child = int.from_bytes(data[at + 8 : at + 12], "big")  # right-most child of the root
    if how == "interior-type":
        data[at] = 0x07
    elif how == "interior-child":
        data[at + 8 : at + 12] = (len(data) // ps + 5).to_bytes(4, "big")
    elif how == "cell-pointer":
        c = _page(ps, child)
        while data[c] == 0x05:  # down to a leaf
            c = _page(ps, int.from_bytes(data[c + 8 : c + 12], "big"))
        data[c + 8 : c + 10] = (ps + 100).to_bytes(2, "big")
    elif how in ("overflow-loop", "overflow-out"):
        # the 9000-byte rows spill: find one leaf cell with an overflow page, point it back
        c = _page(ps, child)
        while data[c] == 0x05:
            c = _page(ps, int.from_bytes(data[c + 8 : c + 12], "big"))
        n = int.from_bytes(data[c + 3 : c + 5], "big")
        ovfl = None
        for k in range(n):
            cell = c + int.from_bytes(data[c + 8 + 2 * k : c + 10 + 2 * k], "big")
            if data[cell] & 0x80:  # payload size >= 128: a 9000-byte row
                size = ((data[cell] & 0x7F) << 7) | data[cell + 1]
                assert size > 9000
                u = ps
                m = (u - 12) * 32 // 255 - 23
                kk = m + (size - m) % (u - 4)
                local = kk if kk <= u - 35 else m
                rowid_len = next(i for i in range(9) if not data[cell + 2 + i] & 0x80) + 1
                ovfl = cell + 2 + rowid_len + local
                break
        assert ovfl is not None
        first = int.from_bytes(data[ovfl : ovfl + 4], "big")
        second_at = _page(ps, first)
        target = first if how == "overflow-loop" else len(data) // ps + 3
        data[second_at : second_at + 4] = target.to_bytes(4, "big")
    elif how == "index-timestamp":
        # a row's timestamp changed in the table only: the index disagrees
        c = _page(ps, child)
        while data[c] == 0x05:
            c = _page(ps, int.from_bytes(data[c + 8 : c + 12], "big"))
        cell = c + int.from_bytes(data[c + 8 : c + 10], "big")
        i = cell
        for _ in range(2):  # payload size, rowid
            while data[i] & 0x80:
                i += 1
            i += 1
        hs = data[i]
        data[i + hs + 1] ^= 0x40  # the timestamp's 2nd byte (topic id is 1 byte or none)
    p.write_bytes(bytes(data))
    return p


@pytest.mark.parametrize(
    "how",
    [
        "interior-type",
        "interior-child",
        "cell-pointer",
        "overflow-loop",
        "overflow-out",
        "index-timestamp",
    ],
)
def test_damage_declines_and_sqlite_reports(tmp_path: Path, how: str) -> None:
    p = _damaged(tmp_path, how, how)
    why = pages_read(p)
    assert isinstance(why, str), how
    for topics in (None, ["/t1"]):
        assert outcome(p, topics, True) == outcome(p, topics, False)


def test_seeded_damage_never_crashes_nor_differs(tmp_path: Path) -> None:
    """600 seeded mutations (bit flips, zeroed ranges, swapped bytes) of a small db3: the
    C scan returns without crashing, and whenever it reads a file, it reads what sqlite3
    reads (sqlite3 reading without error)."""
    import fuzz_harness as fz

    base = write_db3(
        tmp_path / "base.db3", seeded_rows(400, 9, sizes=(84, 700, 3000)), page_size=1024
    )
    data = base.read_bytes()
    rng = np.random.default_rng(1234)
    taken = 0
    for k in range(600):
        mutated, what = fz.mutate(data, rng)
        p = tmp_path / f"m{k % 4}.db3"
        p.write_bytes(mutated)
        try:
            got = pages_read(p, ["/t0", "/t3"])
        except sqlite3.DatabaseError:
            continue  # sqlite cannot read the schema: the caller reports that
        if isinstance(got, str):
            continue
        taken += 1
        assert outcome(p, ["/t0", "/t3"], False) == outcome(p, ["/t0", "/t3"], True), what
    assert taken > 50


# ------------------------------------------------------------------- accelerator switch
def _digest(path: Path) -> str:
    res = outcome(path, None, db3_pages.USE_ACCELERATOR)
    return hashlib.sha256(repr(res).encode()).hexdigest()


def test_accelerator_off_gives_the_same_numbers(tmp_path: Path) -> None:
    """UWVAL_NO_ACCELERATOR=1 switches the page reader off (sqlite3 reads); same result."""
    if not db3_pages.USE_ACCELERATOR:
        pytest.skip("UWVAL_NO_ACCELERATOR is set for this whole run: no 'on' side to compare")
    p = write_db3(tmp_path / "a.db3", seeded_rows(500, 4, sizes=(84, 6000)))
    code = (
        "import sys; sys.path.insert(0, sys.argv[2]); from pathlib import Path;"
        "import uwval.io.db3_pages as d; import test_db3_pages as t;"
        "print(d.USE_ACCELERATOR, t._digest(Path(sys.argv[1])))"
    )
    env = {**os.environ, "UWVAL_NO_ACCELERATOR": "1"}
    env.pop("UWVAL_REQUIRE_ACCELERATOR", None)
    res = subprocess.run(
        [sys.executable, "-c", code, str(p), str(Path(__file__).parent)],
        capture_output=True,
        text=True,
        env=env,
        timeout=60,
        check=True,
    )
    off, digest = res.stdout.split()
    assert off == "False"
    assert db3_pages.USE_ACCELERATOR
    assert digest == _digest(p)


# ------------------------------------------------------------------------ memory
_RSS_CODE = """
import sqlite3, sys
from pathlib import Path
import numpy  # loaded by the scan's result (not at import): not part of what is measured
import uwval.io.db3_pages as d

def hwm():
    for line in open("/proc/self/status"):
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) * 1024

f = Path(sys.argv[1])
con = sqlite3.connect(f"file:{f}?mode=ro&immutable=1", uri=True)
d.index_plan(con, [0])
with open("/proc/self/clear_refs", "w") as fh:  # peak resident size := current
    fh.write("5")
before = hwm()
got = d.scan_pages(f, con, [0, 1, 2, 3], [0])
assert not isinstance(got, str), got
print(hwm() - before, len(got.topics[0][3]))
"""


@pytest.mark.skipif(not Path("/proc/self/clear_refs").exists(), reason="Linux /proc needed")
def test_resident_size_does_not_grow_by_the_file(tmp_path: Path) -> None:
    """The file's pages are dropped from the process as they are read (madvise): reading
    one small topic of a 24 MB file raises the peak resident size by far less than 24 MB
    (without dropping: by the whole file)."""
    rng = np.random.default_rng(8)
    rows = [(1 + k % 3, k, rng.bytes(2000)) for k in range(12_000)]
    rows += [(0, 20_000 + k, rng.bytes(84)) for k in range(200)]
    p = write_db3(tmp_path / "big.db3", rows)
    size = p.stat().st_size
    assert size > 24e6
    res = subprocess.run(
        [sys.executable, "-c", _RSS_CODE, str(p)],
        capture_output=True,
        text=True,
        timeout=60,
        check=True,
    )
    grew, n = map(int, res.stdout.split())
    assert n == 200
    assert grew < size / 4, (grew, size)
