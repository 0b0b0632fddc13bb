"""Headline rows (issue 15): uwval vs evo 1.38.1 on the log shapes users really record.

Inputs come from :mod:`benchmarks.shapes` (many topics interleaved in every chunk, /tf with
five children, an optional 15 Hz 40 kB image topic, hour-long and 10-15 minute logs, each
container format, TUM pairs with 4/6-decimal quaternions). They are generated once into
``$UWVAL_SHAPES_DIR`` (default ``/tmp/uwval-shapes``) and reused by later runs.

Rows, per shape:

- whole command, one topic pair: ``uwval compare LOG --gazebo-topic /gazebo/model_rov_pose
  --unity-topic /unity/model_rov_pose --sync nearest`` (TUM: ``uwval compare REF EST --sync
  nearest``) vs ``evo_ape bag|bag2|tum`` on the same pair; medians of ``reps`` alternating
  runs (uwval, evo, uwval, evo, ...), speed ratio (issue 29's floors: >= 8x, rosbag2
  sqlite3 >= 5x) and peak RSS ratio
  (target: uwval's peak no more than evo's); peak RSS is each command's own (wait4);
- the APE translation RMSE of both tools on that pair, read from their outputs, must agree
  (evo compares the raw numbers, so uwval is run with ``--frame enu`` on containers, whose
  Unity side is in Unity axes: both then compare the same numbers);
- decode of the two selected PoseStamped topics (with their applied-stamp companions) from
  the interleaved container, in process (target >= 2M msg/s);
- ``uwval compare`` of the one-hour MCAP as a user runs it (both pairs, defaults; target < 1 s);
- memory of the image log vs the same log without images (target: no more).

Page cache. How a log's pages sit in the OS page cache changes every reader's figures, and
uwval's most (it maps the file: a fault and an unmap per 4 kB page when the kernel holds the
file in 4 kB pages, one per large folio otherwise). So each shape is measured from a stated
state: **read from disk** (its pages evicted with posix_fadvise, then read once: how a log
recorded earlier sits after it is first read; the kernel's readahead builds large folios)
for every row, and again **as written in 4 kB writes** (how a recorder writing through stdio
leaves a log it has just written: 4 kB folios; the file is rewritten so) for the decode rows
and the image log's whole command and memory rows. Shapes left in another state by earlier
runs would otherwise measure whatever that state was.

``python -m benchmarks --only shapes`` runs just these (about 10-15 minutes on an idle
2-core machine the first time, of which ~3 minutes generate the logs; ~8-10 minutes after).
``--quick`` uses 30 s versions of every shape and 3 repetitions.
"""

from __future__ import annotations

import os
import re
import shutil
import sys
import time
from pathlib import Path

from benchmarks.common import BenchRow, median, run_command
from benchmarks.shapes import SHAPES, Shape, ShapeFiles, generate

#: The shapes measured, in table order; ``--quick`` runs 30 s versions of them.
ROWS = (
    "tum-1h",
    "mcap-1h",
    "mcap-10min-images",
    "mcap-10min",
    "rosbag1-15min",
    "rosbag2-sqlite3-15min",
    "rosbag2-mcap-15min",
)


#: the two page-cache states every shape is measured from (see the module docstring)
READ_FROM_DISK, AS_WRITTEN = "read from disk", "as written in 4 kB writes"


def _files(paths: tuple[Path, ...]) -> list[Path]:
    """The files of a shape (a rosbag2 bag is a folder)."""
    out: list[Path] = []
    for p in paths:
        out.extend(sorted(c for c in p.rglob("*") if c.is_file()) if p.is_dir() else [p])
    return out


def settle(f: ShapeFiles, state: str) -> None:
    """Put the shape's files in the page-cache ``state``: READ_FROM_DISK evicts their pages
    (posix_fadvise DONTNEED, after fsync) and reads them once; AS_WRITTEN rewrites each in
    4 kB writes (same bytes, new file renamed over the old)."""
    for p in _files(f.paths):
        if state == AS_WRITTEN:
            tmp = p.with_name(p.name + ".rewrite")
            with open(p, "rb") as src, open(tmp, "wb", buffering=0) as dst:
                while block := src.read(4096):
                    dst.write(block)
                os.fsync(dst.fileno())
            os.replace(tmp, p)
            continue
        fd = os.open(p, os.O_RDONLY)
        try:
            os.fsync(fd)
            os.posix_fadvise(fd, 0, 0, os.POSIX_FADV_DONTNEED)
            while os.read(fd, 1 << 20):
                pass
        finally:
            os.close(fd)


def shapes_dir() -> Path:
    """Where generated shapes are kept between runs."""
    return Path(os.environ.get("UWVAL_SHAPES_DIR", "/tmp/uwval-shapes"))


def _exe(name: str) -> str:
    here = Path(sys.executable).parent / name
    return str(here) if here.exists() else (shutil.which(name) or name)


def _uwval_cmd(f: ShapeFiles, *extra: str) -> list[str]:
    if f.shape.fmt == "tum":
        return [_exe("uwval"), "compare", *map(str, f.paths), "--sync", "nearest", *extra]
    return [
        _exe("uwval"),
        "compare",
        str(f.paths[0]),
        "--gazebo-topic",
        f.gazebo_topic,
        "--unity-topic",
        f.unity_topic,
        "--sync",
        "nearest",
        *extra,
    ]


def _evo_cmd(f: ShapeFiles) -> list[str]:
    sub = {"tum": "tum", "rosbag1": "bag"}.get(f.shape.fmt, "bag2")
    if sub == "tum":
        return [_exe("evo_ape"), "tum", *map(str, f.paths)]
    return [_exe("evo_ape"), sub, str(f.paths[0]), f.gazebo_topic, f.unity_topic]


def _rmse_evo(cmd: list[str]) -> float:
    import subprocess

    out = subprocess.run(cmd, capture_output=True, text=True, check=True).stdout
    m = re.search(r"rmse\s+([0-9.eE+-]+)", out)
    if m is None:
        raise RuntimeError(f"no rmse in evo's output: {out[-500:]}")
    return float(m.group(1))


def _rmse_uwval(cmd: list[str]) -> float:
    """uwval's APE translation RMSE (the position error norm's RMSE, evo's APE)."""
    import json
    import subprocess

    out = subprocess.run([*cmd, "--json"], capture_output=True, text=True, check=True).stdout
    return float(json.loads(out)["position_error_norm"]["rmse"])


def _decode_rate(f: ShapeFiles, reps: int) -> tuple[float, int]:
    """Selected PoseStamped messages per second, reading the topic pair in one pass."""
    from uwval.io import read_streams

    times = []
    n = 0
    for _ in range(reps):
        t0 = time.perf_counter()
        got = read_streams(f.paths[0], [f.gazebo_topic, f.unity_topic])
        times.append(time.perf_counter() - t0)
        n = sum(len(s) for s in got.values())
        n += sum(0 if s.applied_stamp is None else len(s) for s in got.values())
        del got
    return n / median(times), n


def _decode_row(f: ShapeFiles, reps: int, state: str) -> BenchRow:
    rate, n = _decode_rate(f, reps)
    return BenchRow(
        f"shape {f.shape.name} ({state}): decode selected PoseStamped (+ applied stamps)",
        rate,
        "msg/s",
        target=">= 2M msg/s",
        met=rate >= 2e6,
        notes=f"{n:,} selected msgs of {f.messages:,}, read_streams in process, median",
    )


def _whole_rows(f: ShapeFiles, reps: int, state: str = "") -> list[BenchRow]:
    """The whole command against evo_ape (``reps`` alternating runs): time and peak RSS;
    ``state`` names a page-cache state other than the headline's in the rows' names."""
    uw, evo = _uwval_cmd(f), _evo_cmd(f)
    state = f" ({state})" if state else ""
    runs: dict[str, list[tuple[float, float]]] = {"uwval": [], "evo": []}
    for _ in range(reps):  # alternate: both see the same machine load
        runs["uwval"].append(run_command(uw))
        runs["evo"].append(run_command(evo))
    t_uw, t_evo = (median([r[0] for r in runs[k]]) for k in ("uwval", "evo"))
    m_uw, m_evo = (median([r[1] for r in runs[k]]) for k in ("uwval", "evo"))
    label = f"{f.shape.name} ({f.messages:,} msgs, {f.bytes / 2**20:.0f} MiB)"
    floor = 5.0 if f.shape.fmt == "rosbag2-sqlite3" else 8.0  # issue 29's floors
    sub = evo[1]
    note = f"{reps} alternating runs, medians; evo_ape {sub}, one topic pair"
    return [
        BenchRow(
            f"shape {label}{state}: whole command",
            t_uw,
            "s",
            t_evo,
            f"evo_ape {sub}",
            f">= {floor:g}x faster",
            t_evo / t_uw >= floor,
            notes=note,
        ),
        BenchRow(
            f"shape {f.shape.name}{state}: peak RSS",
            m_uw,
            "MiB",
            m_evo,
            f"evo_ape {sub}",
            "<= evo's",
            m_uw <= m_evo,
            notes=f"ratio = evo / uwval (>= 1 met); {note}",
        ),
    ]


def _shape_rows(f: ShapeFiles, reps: int) -> list[BenchRow]:
    rows = _whole_rows(f, reps)
    evo = _evo_cmd(f)
    sub = evo[1]
    # exactness: the same APE translation RMSE (evo compares raw numbers: uwval --frame enu)
    try:
        extra = () if f.shape.fmt == "tum" else ("--frame", "enu")
        r_uw, r_evo = _rmse_uwval(_uwval_cmd(f, *extra)), _rmse_evo(evo)
        same = abs(r_uw - r_evo) <= 5.1e-7  # evo prints 6 decimals
        rows.append(
            BenchRow(
                f"shape {f.shape.name}: APE translation RMSE",
                r_uw,
                "m",
                r_evo,
                f"evo_ape {sub}",
                "equal to evo's (printed digits)",
                same,
                notes="uwval --sync nearest" + (" --frame enu" if extra else ""),
            )
        )
    except Exception as exc:  # reported, not hidden
        rows.append(
            BenchRow(
                f"shape {f.shape.name}: APE translation RMSE",
                float("nan"),
                "m",
                target="equal to evo's",
                met=False,
                notes=f"could not compare: {exc}"[:200],
            )
        )
    if f.shape.fmt != "tum":
        rows.append(_decode_row(f, reps, READ_FROM_DISK))
    return rows


def _memory_row(img: ShapeFiles, plain: ShapeFiles, reps: int, state: str) -> BenchRow:
    """The image log's peak RSS against the same log without images, both in ``state``."""
    m_img = median([run_command(_uwval_cmd(img))[1] for _ in range(reps)])
    m_plain = median([run_command(_uwval_cmd(plain))[1] for _ in range(reps)])
    return BenchRow(
        f"shape mcap-10min with vs without the image topic ({state}): uwval peak RSS",
        m_img,
        "MiB",
        m_plain,
        "same log without images (uwval)",
        "no more than without images (+5 %)",
        m_img <= m_plain * 1.05,
        notes=f"{reps} runs each, medians",
    )


def selected() -> tuple[str, ...]:
    """The shapes to measure: ``$UWVAL_SHAPES`` (comma-separated names, e.g. ``tum-1h``) or
    all of :data:`ROWS`; rows that need a shape left out are left out too."""
    wanted = [w.strip() for w in os.environ.get("UWVAL_SHAPES", "").split(",") if w.strip()]
    unknown = sorted(set(wanted) - set(ROWS))
    if unknown:
        raise SystemExit(f"UWVAL_SHAPES: unknown shape(s) {unknown}; known: {', '.join(ROWS)}")
    return tuple(r for r in ROWS if r in wanted) if wanted else ROWS


def run(quick: bool = False) -> list[BenchRow]:
    reps = 3 if quick else 5
    d = shapes_dir()
    rows: list[BenchRow] = []
    files: dict[str, ShapeFiles] = {}
    for name in selected():
        sh = SHAPES[name]
        if quick:
            sh = Shape(f"{sh.name}-30s", sh.fmt, 30.0, sh.images)
        print(f"[shapes] {sh.name}: generating/reusing in {d}", file=sys.stderr, flush=True)
        files[name] = f = generate(sh, d)
        settle(f, READ_FROM_DISK)
        rows.extend(_shape_rows(f, reps))
    # memory bounded by the selected topics: the image log costs no more than without images
    img, plain = files.get("mcap-10min-images"), files.get("mcap-10min")
    if img is not None and plain is not None:
        settle(img, READ_FROM_DISK)
        settle(plain, READ_FROM_DISK)
        rows.append(_memory_row(img, plain, reps, READ_FROM_DISK))
    # the floor under every whole-command row: an interpreter that imports numpy, no more
    floor = median([run_command([sys.executable, "-c", "import numpy"])[0] for _ in range(reps)])
    rows.append(
        BenchRow(
            "floor: python -c 'import numpy' (under every whole-command row)",
            floor,
            "s",
            notes=f"{reps} runs, median; 8x evo's time on a shape cannot go below this",
        )
    )
    rows.extend(_startup_rows(d, reps))
    own = files.get("mcap-1h")
    if own is not None:
        rows.append(_own_log_row(own, reps))
    # the same logs as a recorder that just wrote them leaves them: 4 kB pages
    for name, f in files.items():
        if f.shape.fmt == "tum":
            continue
        print(f"[shapes] {f.shape.name}: {AS_WRITTEN}", file=sys.stderr, flush=True)
        settle(f, AS_WRITTEN)
        rows.append(_decode_row(f, reps, AS_WRITTEN))
        if name == "mcap-10min-images":
            rows.extend(_whole_rows(f, reps, AS_WRITTEN))
    if img is not None and plain is not None:
        rows.append(_memory_row(img, plain, reps, AS_WRITTEN))
    return rows


def _startup_rows(d: Path, reps: int) -> list[BenchRow]:
    """Both tools on almost empty inputs, alternating: their start-up and fixed costs, which
    stand under every whole-command row. A 2 s MCAP (100 + 120 poses, the shapes' command,
    evo_ape bag2) and a TUM pair of its first 200 + 120 lines (evo_ape tum)."""
    from uwval.comparison.synthetic import unity_view, vehicle_motion
    from uwval.io.writers import open_writer, write_stream

    log = d / "startup-2s.mcap"
    vehicle = vehicle_motion(100, 50.0)
    with open_writer(log, "mcap") as w:
        write_stream(w, vehicle.topic, vehicle, "enu")
        unity = unity_view(vehicle)
        write_stream(w, unity.topic, unity, unity.frame)
    topics = ("--gazebo-topic", vehicle.topic, "--unity-topic", unity.topic)
    tum = [d / "startup.ref.tum", d / "startup.est.tum"]
    for n, path in zip((200, 120), tum, strict=True):
        path.write_text("".join(f"{k * 0.01:.4f} {k * 1e-3:.4f} 0 0 0 0 0 1\n" for k in range(n)))
    pairs = {
        "a 2 s MCAP (100 + 120 poses, one pair)": (
            [_exe("uwval"), "compare", str(log), *topics, "--sync", "nearest", "--frame", "enu"],
            [_exe("evo_ape"), "bag2", str(log), vehicle.topic, unity.topic],
        ),
        "a 200 + 120 line TUM pair": (
            [_exe("uwval"), "compare", *map(str, tum), "--sync", "nearest"],
            [_exe("evo_ape"), "tum", *map(str, tum)],
        ),
    }
    rows = []
    for what, (uw, evo) in pairs.items():
        times: dict[str, list[float]] = {"uwval": [], "evo": []}
        for _ in range(reps):  # alternate, as the shapes do
            times["uwval"].append(run_command(uw)[0])
            times["evo"].append(run_command(evo)[0])
        rows.append(
            BenchRow(
                f"start-up: compare of {what}",
                median(times["uwval"]),
                "s",
                median(times["evo"]),
                f"evo_ape {evo[1]}",
                notes=f"{reps} alternating runs, medians; under every whole-command row",
            )
        )
    return rows


def _own_log_row(own: ShapeFiles, reps: int) -> BenchRow:
    """A user's whole compare of its own one-hour log (both pairs, defaults)."""
    cmd = [_exe("uwval"), "compare", str(own.paths[0])]
    own_runs = [run_command(cmd) for _ in range(reps)]
    t_own = median([r[0] for r in own_runs])
    return BenchRow(
        f"shape {own.shape.name}: uwval compare LOG (both pairs, defaults)",
        t_own,
        "s",
        target="< 1 s",
        met=t_own < 1.0,
        notes=f"peak RSS {median([r[1] for r in own_runs]):.0f} MiB; {reps} runs, median",
    )
