"""rosbag2 sqlite3 storage: nothing silently lost (issue 29, point 4).

Each case is a file of its own shape, written with Python's sqlite3 the way rosbag2 lays
out its tables, and read through uwval's public readers; every one of them gave a different
number with no warning, or an internal exception as the message, before issue 29.
"""

from __future__ import annotations

import sqlite3
import warnings
from pathlib import Path

import numpy as np
import pytest
from cli_runner import run_uwval

from uwval.errors import LogReadError
from uwval.io import list_topics, read_stream
from uwval.io.encode import encode_pose_stamped
from uwval.io.raw import LogWarning

POSE = "geometry_msgs/msg/PoseStamped"


def _payloads(n: int, x0: float = 0.0) -> list[bytes]:
    """``n`` CDR PoseStamped payloads, x = x0 + index (metres), stamps = index * 0.1 s."""
    t = np.arange(n, dtype=np.int64) * 10**8
    pos = np.column_stack([x0 + np.arange(n, dtype=float), np.zeros(n), np.zeros(n)])
    rows = encode_pose_stamped(t, pos, np.tile([0.0, 0.0, 0.0, 1.0], (n, 1)), "world")
    return [r.tobytes() for r in rows]


def _db3(
    path: Path,
    topics: list[tuple[int, str]],
    rows: list[tuple[object, object, object]],
    *,
    wal: bool = False,
) -> sqlite3.Connection:
    """A rosbag2 sqlite3 storage file: ``topics`` (id, name), ``rows`` (topic_id,
    timestamp, data) in that order. Returns the open connection (closed by the caller)."""
    con = sqlite3.connect(path)
    if wal:
        con.execute("PRAGMA journal_mode=WAL")
        con.execute("PRAGMA wal_autocheckpoint=0")
    con.executescript(
        "CREATE TABLE topics(id INTEGER PRIMARY KEY, name TEXT NOT NULL, type TEXT NOT NULL,"
        " serialization_format TEXT NOT NULL, offered_qos_profiles TEXT NOT NULL);"
        "CREATE TABLE messages(id INTEGER PRIMARY KEY, topic_id INTEGER NOT NULL,"
        " timestamp INTEGER NOT NULL, data BLOB NOT NULL);"
        "CREATE INDEX timestamp_idx ON messages (timestamp ASC);"
    )
    con.executemany(
        "INSERT INTO topics VALUES (?, ?, ?, 'cdr', '')", [(i, n, POSE) for i, n in topics]
    )
    con.executemany("INSERT INTO messages(topic_id, timestamp, data) VALUES (?, ?, ?)", rows)
    con.commit()
    return con


def _metadata(bagdir: Path, counts: dict[str, int]) -> None:
    """rosbag2's metadata.yaml for one storage file ``bag.db3``, with per-topic counts."""
    listed = "".join(
        f"    - topic_metadata:\n        name: {name}\n        type: {POSE}\n"
        f"        serialization_format: cdr\n        offered_qos_profiles: ''\n"
        f"      message_count: {n}\n"
        for name, n in counts.items()
    )
    (bagdir / "metadata.yaml").write_text(
        "rosbag2_bagfile_information:\n  version: 5\n  storage_identifier: sqlite3\n"
        "  relative_file_paths:\n    - bag.db3\n  duration:\n    nanoseconds: 0\n"
        "  starting_time:\n    nanoseconds_since_epoch: 0\n"
        f"  message_count: {sum(counts.values())}\n  topics_with_message_count:\n{listed}"
        "  compression_format: ''\n  compression_mode: ''\n"
    )


def _read(path: Path, topic: str) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """(log times ns, x metres, warnings) of ``topic``, warnings collected, not raised."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        s = read_stream(path, topic, time="log")
    return s.t, s.position[:, 0], list(s.warnings)


def test_db3_through_a_symlink_reads_the_wal_beside_its_target(tmp_path: Path) -> None:
    """30 rows checkpointed into the file, 20 more only in its -wal: the -wal beside the
    real file is found when the .db3 is reached through a symlink in another folder."""
    real = tmp_path / "real"
    real.mkdir()
    data = _payloads(50)
    con = _db3(
        real / "bag.db3", [(1, "/p")], [(1, i * 10**8, data[i]) for i in range(30)], wal=True
    )
    con.execute("PRAGMA wal_checkpoint(TRUNCATE)")
    con.executemany(
        "INSERT INTO messages(topic_id, timestamp, data) VALUES (1, ?, ?)",
        [(i * 10**8, data[i]) for i in range(30, 50)],
    )
    con.commit()
    snap = tmp_path / "snap"  # what a copy of a live recording looks like: -wal not merged
    snap.mkdir()
    for suffix in ("", "-wal", "-shm"):
        (snap / f"bag.db3{suffix}").write_bytes((real / f"bag.db3{suffix}").read_bytes())
    con.close()
    links = tmp_path / "links"
    links.mkdir()
    (links / "bag.db3").symlink_to(snap / "bag.db3")
    t, x, warns = _read(links / "bag.db3", "/p")
    assert len(t) == 50
    np.testing.assert_array_equal(x, np.arange(50.0))
    assert any("write-ahead log" in w for w in warns)
    assert (snap / "bag.db3-wal").stat().st_size > 0  # the files read are left as they were


def test_one_topic_under_two_ids_or_two_spellings_is_read_whole(tmp_path: Path) -> None:
    """``/p`` listed twice (ids 1 and 2) and ``unity/x`` beside ``/unity/x``: every message
    of each name is read, in time order, and the merge is said in a warning."""
    data = _payloads(40)
    rows: list[tuple[object, object, object]] = []
    for i in range(40):
        rows.append((1 + i % 2, i * 10**8, data[i]))  # /p alternately under ids 1 and 2
        rows.append((3 + i % 2, i * 10**8 + 1, data[i]))  # /unity/x, unity/x alternately
    path = tmp_path / "dup.db3"
    _db3(path, [(1, "/p"), (2, "/p"), (3, "/unity/x"), (4, "unity/x")], rows).close()
    for topic in ("/p", "/unity/x"):
        t, x, warns = _read(path, topic)
        assert len(t) == 40, topic
        np.testing.assert_array_equal(x, np.arange(40.0))
        assert any(f"{topic} twice" in w and "dup.db3" in w for w in warns), warns
    with pytest.warns(LogWarning, match="twice or more"):  # a listing says it too
        counts = {i.name: i.count for i in list_topics(path)}
    assert counts == {"/p": 40, "/unity/x": 40}


def test_damaged_db3_that_sqlite_reads_without_complaint_is_read_from_its_rows(
    tmp_path: Path,
) -> None:
    """The timestamp index holds the topic ids (its entries out of order and unequal to
    their rows' timestamps: sqlite's quick_check passes it), one row has a non-integer
    topic_id, and metadata.yaml lists one message more than the storage holds."""
    data = _payloads(20)
    bagdir = tmp_path / "bag"
    bagdir.mkdir()
    path = bagdir / "bag.db3"
    rows: list[tuple[object, object, object]] = [(1, 10**9 + i * 10**8, data[i]) for i in range(20)]
    rows[7] = (1.5, rows[7][1], rows[7][2])
    con = _db3(path, [(1, "/p")], rows)
    con.executescript(
        "DROP INDEX timestamp_idx; CREATE INDEX timestamp_idx ON messages (topic_id ASC);"
        "PRAGMA writable_schema=ON;"
        "UPDATE sqlite_master SET sql='CREATE INDEX timestamp_idx ON messages (timestamp ASC)'"
        " WHERE name='timestamp_idx';"
    )
    con.commit()
    con.close()
    _metadata(bagdir, {"/p": 21})
    t, x, warns = _read(bagdir, "/p")
    keep = [i for i in range(20) if i != 7]
    np.testing.assert_array_equal(t, [10**9 + i * 10**8 for i in keep])
    np.testing.assert_array_equal(x, np.array(keep, dtype=float))
    assert any("bag.db3" in w and "row 8" in w and "topic_id" in w for w in warns), warns
    assert any("timestamp index disagrees with the messages table" in w for w in warns), warns
    assert any("lists 21 messages on /p" in w and "holds 19" in w for w in warns), warns


def test_a_blob_that_is_not_a_blob_is_named_not_an_internal_exception(tmp_path: Path) -> None:
    """A message row whose data is an integer: the row is named and dropped with a
    warning, the others are read; through the command line, one line and no traceback."""
    data = _payloads(10)
    rows: list[tuple[object, object, object]] = [(1, i * 10**8, data[i]) for i in range(10)]
    rows[3] = (1, rows[3][1], 12345)
    rows += [(2, i * 10**8 + 5, data[i]) for i in range(10)]
    path = tmp_path / "ints.db3"
    _db3(path, [(1, "/gazebo/model_rov_pose"), (2, "/unity/model_rov_pose")], rows).close()
    t, _x, warns = _read(path, "/gazebo/model_rov_pose")
    assert len(t) == 9
    assert any(
        "ints.db3" in w and "messages row 4" in w and "data is of type integer, not blob" in w
        for w in warns
    ), warns
    assert not any("TypeError" in w for w in warns)
    res = run_uwval("compare", path, "--json")
    assert "Traceback" not in res.stderr
    assert "TypeError" not in res.stderr + res.stdout
    assert "messages row 4" in res.stderr, res.stderr


@pytest.mark.parametrize("stamp", ["abc", b"ab", 2.5])
def test_a_timestamp_that_is_not_an_integer_is_named_and_skipped(
    tmp_path: Path, stamp: object
) -> None:
    """A row whose timestamp sqlite holds as text, blob or real, on the topic read and on
    another: each is named and skipped, counted as a damaged row, and the topics' counts
    and spans still come out (a text or blob stamp was an internal ValueError before)."""
    data = _payloads(10)
    rows: list[tuple[object, object, object]] = [(1, i * 10**8, data[i]) for i in range(10)]
    rows += [(2, 5 + i * 10**8, data[i]) for i in range(10)]
    rows[3], rows[14] = (1, stamp, data[3]), (2, stamp, data[4])
    path = tmp_path / "stamps.db3"
    _db3(path, [(1, "/p"), (2, "/q")], rows).close()
    t, x, warns = _read(path, "/p")
    np.testing.assert_array_equal(x, [i for i in range(10) if i != 3])
    assert len(t) == 9
    assert any("messages row 4: timestamp is of type" in w for w in warns), warns
    assert any("messages row 15: timestamp is of type" in w for w in warns), warns
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        spans = {i.name: (i.count, i.start_ns, i.end_ns) for i in list_topics(path)}
    assert spans["/p"] == (10, 0, 9 * 10**8)  # spans of the numbers (a real counts, as ns)
    assert spans["/q"] == (10, 2 if stamp == 2.5 else 5, 5 + 9 * 10**8)


@pytest.mark.parametrize("odd", ["odd#dir", "odd?dir", "odd%23dir"])
def test_paths_with_uri_characters_open_the_file_named(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, odd: str
) -> None:
    """A bag under ``odd#dir/`` (``?``, ``%23`` alike) is read from there, not from ``./odd``
    (which exists here and holds another recording)."""
    monkeypatch.chdir(tmp_path)
    decoy = _payloads(5, x0=100.0)
    _db3(tmp_path / "odd", [(2, "/p")], [(2, i * 10**8, decoy[i]) for i in range(5)]).close()
    data = _payloads(30)
    (tmp_path / odd).mkdir()
    _db3(tmp_path / odd / "bag.db3", [(1, "/p")], [(1, i * 10**8, data[i]) for i in range(30)])
    for path in (Path(odd) / "bag.db3", tmp_path / odd / "bag.db3"):
        t, x, _warns = _read(path, "/p")
        assert len(t) == 30, path
        np.testing.assert_array_equal(x, np.arange(30.0))
    bagdir = tmp_path / odd / "bag2"  # a rosbag2 directory under the odd name too
    bagdir.mkdir()
    (tmp_path / odd / "bag.db3").rename(bagdir / "bag.db3")
    _metadata(bagdir, {"/p": 30})
    t, _x, warns = _read(Path(odd) / "bag2", "/p")
    assert len(t) == 30 and not warns


def test_unreadable_storage_names_the_file_in_one_line(tmp_path: Path) -> None:
    path = tmp_path / "x.db3"
    path.write_bytes(b"SQLite format 3\0" + bytes(200))
    with pytest.raises(LogReadError, match=r"x\.db3: ") as e:
        read_stream(path, "/p")
    assert "\n" not in str(e.value)
