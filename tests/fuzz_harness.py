"""Fuzz harness for the log readers: mutate intact logs, read them, classify what happened.

Each case takes one intact log (written by the real libraries, see :mod:`io_loggen`),
applies one seeded mutation (bit flips, a zeroed range, a truncation, swapped byte ranges) to
its storage file, reads the pose topics (``read_streams``) and the inspect view
(``topic_times``) in a worker process, and classifies the outcome:

* ``same``: the numbers equal the intact file's;
* ``warned``: they differ (or fewer samples), and the streams carry a warning / dropped count;
* ``error``: a uwval error (one line, no traceback);
* ``faithful``: they differ silently, but exactly as the reference library (rosbags / mcap)
  reads the mutated file: the bytes of a number changed in a format without a checksum
  (uncompressed ROS 1 chunk, sqlite row); no reader can tell;
* ``unverified``: they differ silently and the reference library cannot read the mutated
  file at all, so there is nothing to check them against (listed, to be read by hand);
* ``silent``: they differ from the intact file with no warning and from the reference: a bug;
* ``traceback``: any other exception: a bug;
* ``hang``: no answer within the per-case timeout: a bug.

Run by hand: ``python tests/fuzz_harness.py --n 10000 [--format mcap] [--seed 1]``.
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import os
import shutil
import sys
import tempfile
import time
import traceback
import warnings
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import io_loggen as gen

#: Container formats and the intact variants each is fuzzed from.
FORMATS: dict[str, list[tuple[str, str]]] = {
    "mcap": [("mcap", "zstd"), ("mcap", "lz4"), ("mcap", "none")],
    "bag": [("bag", "none"), ("bag", "bz2"), ("bag", "lz4")],
    "rosbag2-sqlite3": [("rosbag2-sqlite3", "")],
    "rosbag2-mcap": [("rosbag2-mcap", "")],
    "tum": [("tum", "")],
    "csv": [("csv", "")],
}
TEXT = "trajectory"  # the one stream of a text file
TOPICS = [gen.GAZEBO, gen.UNITY]
CASE_TIMEOUT = 30.0


def make_bases(root: Path) -> dict[str, list[Path]]:
    """The intact logs, per container format."""
    out: dict[str, list[Path]] = {}
    root.mkdir(parents=True, exist_ok=True)
    for name, variants in FORMATS.items():
        out[name] = []
        for k, (fmt, comp) in enumerate(variants):
            suffix = {"mcap": ".mcap", "bag": ".bag", "tum": ".txt", "csv": ".csv"}.get(fmt, "")
            p = root / f"{name}-{comp or 'x'}{suffix}"
            if fmt in ("tum", "csv"):
                _write_text(p, fmt, seed=k)
            else:
                gen.write_log(p, fmt, compression=comp or "zstd", seed=k, seconds=1.5)
            out[name].append(p)
    return out


def _write_text(path: Path, fmt: str, seed: int, n: int = 300) -> None:
    """A TUM (quaternions rounded to 6 decimals, as real ground truths) or CSV trajectory."""
    rng = np.random.default_rng(seed)
    t = 1_700_000_000.0 + np.arange(n) * 0.01
    p = np.cumsum(rng.normal(size=(n, 3)) * 0.01, axis=0)
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1)[:, None]
    lines = []
    if fmt == "tum":
        lines.append("# timestamp tx ty tz qx qy qz qw")
        for i in range(n):
            lines.append(
                f"{t[i]:.4f} {p[i, 0]:.6f} {p[i, 1]:.6f} {p[i, 2]:.6f} "
                + " ".join(f"{v:.6f}" for v in q[i])
            )
    else:
        lines.append("time,x,y,z,qx,qy,qz,qw")
        for i in range(n):
            lines.append(
                f"{t[i]:.4f},{p[i, 0]:.6f},{p[i, 1]:.6f},{p[i, 2]:.6f},"
                + ",".join(f"{v:.6f}" for v in q[i])
            )
    path.write_text("\n".join(lines) + "\n")


def _topics(path: Path) -> list[str]:
    return [TEXT] if path.suffix in (".txt", ".csv") else TOPICS


#: The bit flips of the last bit-flip mutation: (byte offset, bit) in the order applied.
LAST_FLIPS: list[tuple[int, int]] = []


def flip(data: bytes, flips: list[tuple[int, int]]) -> bytes:
    """``data`` with the given (byte offset, bit) flips applied."""
    b = bytearray(data)
    for w, bit in flips:
        b[w] ^= 1 << bit
    return bytes(b)


def mutate(data: bytes, rng: np.random.Generator) -> tuple[bytes, str]:
    """One mutation of ``data``; returns the new bytes and what was done (bit flips also
    in :data:`LAST_FLIPS`, emptied by every other mutation)."""
    b = bytearray(data)
    n = len(b)
    kind = int(rng.integers(0, 4))
    LAST_FLIPS.clear()
    if kind == 0:
        k = int(rng.integers(1, 9))
        where = rng.integers(0, n, size=k)
        LAST_FLIPS.extend((int(w), int(rng.integers(0, 8))) for w in where)
        return flip(data, LAST_FLIPS), f"flip {k} bit(s) at {sorted(int(x) for x in where)[:3]}"
    if kind == 1:
        ln = int(rng.choice([1, 4, 8, 16, 64, 256, 4096]))
        at = int(rng.integers(0, max(1, n - ln)))
        b[at : at + ln] = bytes(min(ln, n - at))
        return bytes(b), f"zero {ln} bytes at {at}"
    if kind == 2:
        at = int(rng.integers(1, n))
        return bytes(b[:at]), f"truncate at {at} of {n}"
    ln = int(rng.choice([1, 2, 8, 32, 256]))
    a = int(rng.integers(0, max(1, n - ln)))
    c = int(rng.integers(0, max(1, n - ln)))
    seg_a, seg_c = bytes(b[a : a + ln]), bytes(b[c : c + ln])
    b[a : a + ln] = seg_c
    b[c : c + ln] = seg_a
    return bytes(b), f"swap {ln} bytes at {a} and {c}"


def read_all(path: Path) -> dict[str, Any]:
    """What uwval reads: per pose topic (t, position, orientation, applied), warnings."""
    from uwval.io import read_stream, read_streams, topic_times

    with warnings.catch_warnings(record=True):
        warnings.simplefilter("always")
        if path.suffix in (".txt", ".csv"):
            streams = {TEXT: read_stream(path, "")}
        else:
            streams = read_streams(path, TOPICS)
            topic_times(path)
    out: dict[str, Any] = {"warned": {}, "streams": {}}
    for t, s in streams.items():
        out["streams"][t] = (s.t, s.position, s.orientation, s.applied_stamp)
        out["warned"][t] = bool(s.warnings or s.dropped)
    return out


def _same(
    a: dict[str, Any], b: dict[str, Any], with_applied: bool = True, topics: Any = None
) -> bool:
    for t in topics if topics is not None else list(a["streams"]):
        x, y = a["streams"][t], b["streams"][t]
        for k in range(4 if with_applied else 3):
            u, v = x[k], y[k]
            if (u is None) != (v is None):
                return False
            if u is not None and (u.shape != v.shape or not np.array_equal(u, v)):
                return False
    return True


def reference(path: Path) -> dict[str, Any] | None:
    """The pose topics as the reference libraries read the (mutated) file; None if they fail."""
    from uwval.posestream import PoseStream

    if path.suffix in (".txt", ".csv"):
        return _text_reference(path)
    try:
        rows: dict[str, list[tuple[int, tuple[float, ...]]]] = {t: [] for t in TOPICS}
        applied: dict[int, int] = {}
        unity_lt: list[tuple[int, int]] = []
        for topic, lt, msg in _ref_messages(path):
            if msg is None:
                continue
            if topic == gen.APPLIED:
                applied[lt] = int(msg.stamp.sec) * 10**9 + int(msg.stamp.nanosec)
                continue
            h = msg.header
            if topic == gen.UNITY:
                unity_lt.append((int(h.stamp.sec) * 10**9 + int(h.stamp.nanosec), lt))
            p, q = msg.pose.position, msg.pose.orientation
            rows[topic].append(
                (
                    int(h.stamp.sec) * 10**9 + int(h.stamp.nanosec),
                    (p.x, p.y, p.z, q.x, q.y, q.z, q.w),
                )
            )
        out: dict[str, Any] = {"warned": {}, "streams": {}}
        for t, r in rows.items():
            lts = [lt for _st, lt in unity_lt] if t == gen.UNITY else []
            app = (
                np.array([applied[x] for x in lts], dtype=np.int64)
                if lts and all(x in applied for x in lts)
                else None
            )
            s = PoseStream.from_arrays(
                np.array([x[0] for x in r], dtype=np.int64),
                np.array([x[1][:3] for x in r]).reshape(-1, 3),
                np.array([x[1][3:] for x in r]).reshape(-1, 4),
                applied_stamp=app,
            )
            out["streams"][t] = (s.t, s.position, s.orientation, s.applied_stamp)
        return out
    except Exception as exc:
        if os.environ.get("UWVAL_FUZZ_DEBUG"):
            traceback.print_exception(exc)
        return None


def _text_reference(path: Path) -> dict[str, Any] | None:
    """A text trajectory as numpy's loadtxt (TUM) or pandas (CSV) reads it."""
    from uwval.posestream import PoseStream

    try:
        if path.suffix == ".txt":
            a = np.loadtxt(path, comments="#", ndmin=2)
        else:
            import pandas as pd

            a = pd.read_csv(path).to_numpy(dtype=np.float64)
        if a.shape[1] != 8:
            return None
        from uwval.io.stamps import ns_from_seconds

        s = PoseStream.from_arrays(ns_from_seconds(a[:, 0]), a[:, 1:4], a[:, 4:8])
    except Exception as exc:
        if os.environ.get("UWVAL_FUZZ_DEBUG"):
            traceback.print_exception(exc)
        return None
    return {"warned": {}, "streams": {TEXT: (s.t, s.position, s.orientation, None)}}


def _ref_messages(path: Path) -> Any:
    """(topic, log time, rosbags message) of the pose and applied topics, read by the
    reference libraries; a message they cannot deserialize is skipped (only that one)."""
    from uwval.io.ros import typestore

    want = (*TOPICS, gen.APPLIED)
    types = {gen.APPLIED: "std_msgs/msg/Header"}

    def de(topic: str, data: bytes, ros: int) -> Any:
        typ = types.get(topic, "geometry_msgs/msg/PoseStamped")
        try:
            if ros == 1:
                return typestore(1).deserialize_ros1(data, typ)
            return typestore(2).deserialize_cdr(data, typ)
        except Exception:
            return None

    if path.is_dir() and any(path.glob("*.db3")):
        import sqlite3

        db = next(iter(sorted(path.glob("*.db3"))))
        con = sqlite3.connect(f"file:{db}?mode=ro&immutable=1", uri=True)
        try:
            rows = con.execute(
                "SELECT topics.name, messages.timestamp, messages.data FROM messages "
                "JOIN topics ON topics.id = messages.topic_id ORDER BY messages.timestamp"
            ).fetchall()
        finally:
            con.close()
        for name, t, data in rows:
            if name in want:
                yield name, t, de(name, bytes(data), 2)
        return
    if path.is_dir():
        path = next(iter(sorted(path.glob("*.mcap"))))
    if path.suffix == ".bag":
        from rosbags.rosbag1 import Reader as Bag1Reader

        with Bag1Reader(path) as r:
            conns = [c for c in r.connections if c.topic in want]
            for c, t, data in r.messages(connections=conns):
                yield c.topic, t, de(c.topic, data, 1)
        return
    from mcap.reader import make_reader

    with open(path, "rb") as fh:
        reader = make_reader(fh, validate_crcs=True)
        for _s, ch, m in reader.iter_messages(topics=list(want)):
            yield ch.topic, m.log_time, de(ch.topic, m.data, 2)


def run_case(base: Path, intact: dict[str, Any], seed: int, work: Path) -> tuple[str, str]:
    """Mutate ``base`` with ``seed``, read it, classify; returns (outcome, detail)."""
    from uwval.errors import UwvalError

    rng = np.random.default_rng(seed)
    target = work / base.name
    if target.exists():
        shutil.rmtree(target) if target.is_dir() else target.unlink()
    if base.is_dir():
        shutil.copytree(base, target)
        victims = [p for p in target.iterdir() if p.is_file()]
        # the storage file mostly; metadata.yaml sometimes
        victim = sorted(victims, key=lambda p: p.name != "metadata.yaml")[
            0 if rng.random() < 0.1 else -1
        ]
    else:
        shutil.copy(base, target)
        victim = target
    original = victim.read_bytes()
    data, what = mutate(original, rng)
    flips = list(LAST_FLIPS)
    victim.write_bytes(data)
    detail = f"{base.name} seed {seed}: {what} in {victim.name}"
    try:
        got = read_all(target)
    except UwvalError as exc:
        msg = str(exc)
        if "\n" in msg:
            return "traceback", f"{detail}: multi-line error {msg!r}"
        return "error", detail
    except Exception:
        return "traceback", detail + "\n" + traceback.format_exc()
    if _same(got, intact):
        return "same", detail
    # every stream whose numbers differ must say so itself
    differ = [t for t in _topics(target) if not _same(got, intact, topics=[t])]
    unsaid = [t for t in differ if not got["warned"][t]]
    if not unsaid:
        return "warned", detail
    ref = reference(target)
    if ref is None and flips:
        explained = _explain_with_fewer_flips(target, victim, original, flips, got, unsaid)
        if explained:
            return "faithful", f"{detail} ({explained})"
    if ref is None:
        # the reference library cannot read the mutated file at all (e.g. rosbags refuses a
        # bag whose index section is damaged): nothing to check the numbers against
        return "unverified", f"{detail} (differs silently: {', '.join(unsaid)})"
    if _same(got, ref, topics=unsaid):
        return "faithful", detail
    return "silent", f"{detail} (differs silently: {', '.join(unsaid)})"


def _explain_with_fewer_flips(
    target: Path,
    victim: Path,
    original: bytes,
    flips: list[tuple[int, int]],
    got: dict[str, Any],
    unsaid: list[str],
) -> str:
    """Why numbers differ silently in a file the reference cannot open, when bit flips did it.

    A flip that on its own makes the reference refuse the file (e.g. a non-UTF-8 byte in an
    MCAP Channel or Schema record, which uwval does not need) "breaks" the reference. With
    the breakers left out, the reference reads the file again; if uwval reads the same
    numbers from that file as from the whole mutation, and those numbers are the
    reference's, the silent difference came from flips in bytes no checksum protects (a
    payload in a chunk without CRC): "faithful". Returns the explanation, or "" if not.
    """
    try:
        breakers = []
        for f in flips:
            victim.write_bytes(flip(original, [f]))
            if reference(target) is None:
                breakers.append(f)
        rest = [f for f in flips if f not in breakers]
        if not breakers or not rest:
            return ""
        victim.write_bytes(flip(original, rest))
        ref = reference(target)
        if ref is None:
            return ""
        without = read_all(target)
        if not (_same(without, got, topics=unsaid) and _same(without, ref, topics=unsaid)):
            return ""
        return (
            f"the reference refuses the file for flip(s) {breakers} alone; without them it "
            f"reads the same numbers as uwval: {', '.join(unsaid)} changed in unprotected bytes"
        )
    except Exception:
        return ""
    finally:
        victim.write_bytes(flip(original, flips))


def _same_array(u: Any, v: Any) -> bool:
    if u is None or v is None:
        return u is None and v is None
    return bool(u.shape == v.shape and np.array_equal(u, v))


def _worker(bases: list[str], intacts: dict[str, Any], jobs: Any, results: Any, work: str) -> None:
    while True:
        job = jobs.get()
        if job is None:
            return
        base, seed = job
        results.put((base, seed, *run_case(Path(base), intacts[base], seed, Path(work))))


def fuzz(
    n: int, formats: list[str] | None = None, seed: int = 0, *, timeout: float = CASE_TIMEOUT
) -> dict[str, Counter[str]]:
    """Run ``n`` mutated inputs per container format; returns outcome counts per format
    and prints every bug (traceback, hang, silent) with its seed."""
    root = Path(tempfile.mkdtemp(prefix="uwval-fuzz-"))
    try:
        bases = make_bases(root / "base")
        intacts = {str(p): read_all(p) for ps in bases.values() for p in ps}
        counts: dict[str, Counter[str]] = {}
        ctx = mp.get_context("fork")
        for name in formats or list(FORMATS):
            counts[name] = Counter()
            paths = bases[name]
            todo = [(str(paths[k % len(paths)]), seed * 10**7 + k) for k in range(n)]
            work = root / f"work-{name}"
            work.mkdir()
            while todo:
                jobs, results = ctx.Queue(), ctx.Queue()
                for j in todo:
                    jobs.put(j)
                jobs.put(None)
                proc = ctx.Process(target=_worker, args=([], intacts, jobs, results, str(work)))
                proc.start()
                done = 0
                while done < len(todo):
                    try:
                        base, s, outcome, detail = results.get(timeout=timeout)
                    except Exception:  # queue.Empty: the current case hangs
                        base, s = todo[done]
                        outcome, detail = (
                            "hang",
                            f"{Path(base).name} seed {s}: no answer in {timeout} s",
                        )
                        proc.kill()
                        proc.join()
                        counts[name][outcome] += 1
                        print(f"[{name}] {outcome}: {detail}", flush=True)
                        done += 1
                        break
                    counts[name][outcome] += 1
                    if outcome in ("traceback", "silent", "unverified"):
                        print(f"[{name}] {outcome}: {detail}", flush=True)
                    done += 1
                todo = todo[done:]
                proc.join(timeout=5)
                if proc.is_alive():
                    proc.kill()
        return counts
    finally:
        shutil.rmtree(root, ignore_errors=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=int(os.environ.get("UWVAL_FUZZ_N", "1000")))
    ap.add_argument("--format", action="append", choices=list(FORMATS))
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    t0 = time.monotonic()
    counts = fuzz(args.n, args.format, args.seed)
    for name, c in counts.items():
        print(
            f"{name}: {sum(c.values())} inputs: "
            + ", ".join(f"{k} {v}" for k, v in sorted(c.items()))
        )
    print(f"{time.monotonic() - t0:.0f} s")


if __name__ == "__main__":
    main()
