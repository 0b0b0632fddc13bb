"""Compare-engine speed against evo 1.38.1 on a deterministic 360,000-pose pair (issue 3 item 9).

(a) whole command: ``uwval compare a.tum b.tum --sync nearest`` vs ``evo_ape tum a.tum b.tum``
    (wall time and peak RSS of the child process; targets >= 10x faster, <= 1/5 memory);
(b) engine alone on in-memory arrays: association + metrics (uwval ``compare(sync='nearest')``
    vs evo's ``associate_trajectories`` + ``metrics.APE`` + statistics) and SE(3) alignment
    (uwval Umeyama + apply vs ``PoseTrajectory3D.align``); target >= 50x;
(c) the same pair as MCAP PoseStamped logs, whole command: target < 1 s.

The whole command is measured as ``python -m uwval`` and as the installed ``uwval`` console
script (both go through typer, the only parser). Peak RSS is the command's own
(``benchmarks.common.run_command``).

Files are generated once per run into a temporary directory (seeded, identical every run).
"""

from __future__ import annotations

import shutil
import sys
import tempfile
from pathlib import Path

import numpy as np

from benchmarks.common import BenchRow, alternate, median, run_command

N_POSES = 360_000
QUICK_POSES = 36_000


def _make_pair(directory: Path, n: int) -> tuple[Path, Path, Path, Path]:
    """Reference and estimate (3 ms clock skew, 1 cm noise) as TUM files and MCAP logs."""
    from uwval.comparison.synthetic import vehicle_motion
    from uwval.io.tum import write_tum
    from uwval.io.writers import open_writer, write_stream

    ref = vehicle_motion(
        n, rate_hz=100.0, seed=0, t0_ns=1_700_000_000_000_000_000, topic="/gazebo/model_rov_pose"
    )
    noise = np.random.default_rng(1).normal(0.0, 0.01, (n, 3))
    est = ref.with_(
        t=ref.t + np.int64(3_000_000), position=ref.position + noise, topic="/unity/model_rov_pose"
    )
    a, b = directory / "a.tum", directory / "b.tum"
    write_tum(a, ref)
    write_tum(b, est)
    ma, mb = directory / "a.mcap", directory / "b.mcap"
    for path, stream in ((ma, ref), (mb, est)):
        with open_writer(path, "mcap") as w:
            write_stream(w, stream.topic, stream, "enu")
    return a, b, ma, mb


def _evo_ape_cmd() -> str:
    exe = shutil.which("evo_ape") or str(Path(sys.executable).parent / "evo_ape")
    return exe


def _whole_command(a: Path, b: Path, ma: Path, mb: Path, reps: int) -> list[BenchRow]:
    uw = [sys.executable, "-m", "uwval", "compare", str(a), str(b), "--sync", "nearest"]
    script = Path(sys.executable).parent / "uwval"  # the console script users run
    light = [
        str(script) if script.exists() else shutil.which("uwval") or "uwval",
        "compare",
        str(a),
        str(b),
        "--sync",
        "nearest",
    ]
    evo = [_evo_ape_cmd(), "tum", str(a), str(b)]
    runs: dict[str, list[tuple[float, float]]] = {"uwval": [], "light": [], "evo": []}
    for _ in range(reps):  # alternate so all see the same machine load
        runs["uwval"].append(run_command(uw))
        runs["light"].append(run_command(light))
        runs["evo"].append(run_command(evo))
    t_evo = median([r[0] for r in runs["evo"]])
    m_evo = max(r[1] for r in runs["evo"])
    rows = []
    for key, label in (("uwval", "python -m uwval"), ("light", "uwval console script")):
        t_uw = median([r[0] for r in runs[key]])
        m_uw = max(r[1] for r in runs[key])
        rows += [
            BenchRow(
                f"compare TUM 360k, whole command (nearest), {label}",
                t_uw,
                "s",
                t_evo,
                "evo_ape 1.38.1",
                ">= 10x faster",
                t_evo / t_uw >= 10.0,
                notes=f"{reps} alternating runs, medians",
            ),
            BenchRow(
                f"compare TUM 360k, peak RSS, {label}",
                m_uw,
                "MiB",
                m_evo,
                "evo_ape 1.38.1",
                "<= 1/5 of evo's",
                m_uw <= m_evo / 5.0,
                notes="max over runs",
            ),
        ]
    mc = [
        sys.executable,
        "-m",
        "uwval",
        "compare",
        str(ma),
        str(mb),
        "--sync",
        "nearest",
        "--gazebo-topic",
        "/gazebo/model_rov_pose",
        "--unity-topic",
        "/unity/model_rov_pose",
    ]
    mcap_runs = [run_command(mc) for _ in range(reps)]
    t_mc = median([r[0] for r in mcap_runs])
    rows.append(
        BenchRow(
            "compare MCAP 360k PoseStamped, whole command",
            t_mc,
            "s",
            target="< 1 s",
            met=t_mc < 1.0,
            notes=f"peak RSS {max(r[1] for r in mcap_runs):.0f} MiB",
        )
    )
    return rows


def _engine(a: Path, b: Path, reps: int) -> list[BenchRow]:
    from evo.core import metrics, sync
    from evo.tools import file_interface

    from uwval.comparison import compare
    from uwval.comparison.align import estimate_alignment
    from uwval.io.tum import read_tum

    ref, est = read_tum(a), read_tum(b)
    evo_ref = file_interface.read_tum_trajectory_file(str(a))
    evo_est = file_interface.read_tum_trajectory_file(str(b))

    from uwval.comparison.stats import norm_stats
    from uwval.comparison.sync import associate_nearest, index_or_slice

    def uw_assoc() -> float:
        """The same work as evo: association, position-error norm, its statistics (with the
        engine's own row selection: views when the matches are a contiguous run)."""
        m = associate_nearest(ref, est, max_diff=0.01)
        d = est.position[index_or_slice(m.other_idx)] - ref.position[index_or_slice(m.ref_idx)]
        return float(norm_stats(np.sqrt(np.einsum("ij,ij->i", d, d)))["rmse"])

    def uw_full() -> float:
        """Everything ``uwval compare`` computes (6 axes, Pearson, rotation, counts...)."""
        return float(compare(ref, est, sync="nearest").stats["position_error_norm"]["rmse"])

    def evo_assoc() -> float:
        r, e = sync.associate_trajectories(evo_ref, evo_est, max_diff=0.01)
        ape = metrics.APE(metrics.PoseRelation.translation_part)
        ape.process_data((r, e))
        return float(ape.get_all_statistics()["rmse"])

    assert abs(uw_assoc() - evo_assoc()) < 1e-9, "uwval and evo disagree"
    assert abs(uw_full() - evo_assoc()) < 1e-9, "uwval and evo disagree"
    t_uw, t_full, t_evo = alternate([uw_assoc, uw_full, evo_assoc], reps)

    r_sync, e_sync = sync.associate_trajectories(evo_ref, evo_est, max_diff=0.01)
    matched = compare(ref, est, sync="nearest")
    rp, rq = matched.reference.position, matched.reference.orientation
    op, oq = matched.other.position, matched.other.orientation

    def uw_align() -> None:
        estimate_alignment("se3", rp, rq, op, oq).apply(op, oq)

    def evo_align() -> None:
        import copy

        copy.deepcopy(e_sync).align(r_sync)  # align mutates: work on a copy, as evo_ape does

    def uw_align_copy() -> None:  # same copy cost on both sides for fairness
        op.copy()
        oq.copy()
        uw_align()

    a_uw, a_evo = alternate([uw_align_copy, evo_align], reps)
    return [
        BenchRow(
            "engine: nearest association + metrics (360k)",
            median(t_uw),
            "s",
            median(t_evo),
            "evo sync + APE + stats",
            ">= 50x faster",
            median(t_evo) / median(t_uw) >= 50.0,
            notes="same work: association, position-error norm, evo's statistics",
        ),
        BenchRow(
            "engine: full uwval compare() metrics (360k)",
            median(t_full),
            "s",
            median(t_evo),
            "evo sync + APE + stats",
            "(more work than evo)",
            notes="per-axis MAE/RMSE/max/p95/bias/std + Pearson r/p/CI x6, geodesic",
        ),
        BenchRow(
            "engine: SE(3) Umeyama alignment + apply (360k)",
            median(a_uw),
            "s",
            median(a_evo),
            "evo PoseTrajectory3D.align",
            ">= 50x faster",
            median(a_evo) / median(a_uw) >= 50.0,
        ),
    ]


def _compile_bytecode() -> None:
    """Write uwval's .pyc files first, as an installed package has them: an editable checkout
    under PYTHONDONTWRITEBYTECODE would otherwise compile edited modules in every timed run."""
    import compileall

    import uwval

    compileall.compile_dir(Path(uwval.__file__).parent, quiet=1)


def run(quick: bool = False) -> list[BenchRow]:
    """Generate the pair, measure (a), (b), (c). ``quick``: 36k poses, fewer repetitions."""
    n = QUICK_POSES if quick else N_POSES
    reps = 1 if quick else 5
    _compile_bytecode()
    with tempfile.TemporaryDirectory(prefix="uwval-bench-compare-") as tmp:
        a, b, ma, mb = _make_pair(Path(tmp), n)
        rows = _whole_command(a, b, ma, mb, reps)
        rows += _engine(a, b, reps)
    if quick:
        for row in rows:
            row.notes = (row.notes + "; " if row.notes else "") + f"quick: {n} poses"
    return rows


if __name__ == "__main__":
    quick = "--quick" in sys.argv
    for row in run(quick=quick):
        ratio = f"{row.ratio:.1f}x" if row.ratio else "-"
        peer = f"{row.peer:.4g}" if row.peer is not None else "-"
        print(
            f"{row.name:50s} uwval {row.uwval:.4g} {row.unit:4s} peer {peer:>8s} "
            f"ratio {ratio:>7s} target {row.target:16s} met {row.met}  {row.notes}"
        )
