"""Results, gate and report speed: tidy table build, CI gate, HTML and PDF report of an experiment.

No peer tool builds these reports, so rows carry targets: the gate must stay interactive on
a large sweep (hundreds of runs), and the report of the default experiment (54 runs, as
``uwval demo`` makes it) must take <= 10 s for HTML + PDF (issue 33.4). The 54 runs are
simulated and compared once (not timed); the report is then timed, its stages in the notes.
Run: ``python -m benchmarks.bench_reports`` (``--quick`` for a smoke run: no 54-run rows).
"""

from __future__ import annotations

import json
import sys
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.common import BenchRow, alternate, median

AXES = ("x", "y", "z", "roll", "pitch", "yaw")


def _comparison_json(rng: np.random.Generator) -> dict[str, Any]:
    """A LogComparison-shaped JSON (two topics) with random but plausible metrics."""

    def one() -> dict[str, Any]:
        axes = {}
        for a in AXES:
            mae = float(rng.uniform(1e-4, 1e-2))
            r = float(rng.uniform(0.99, 1.0)) if a != "z" else None
            axes[a] = {
                "mae": mae,
                "rmse": mae * 1.2,
                "max": mae * 3,
                "p95": mae * 2,
                "bias": mae * 0.1,
                "std": mae,
                "pearson_r": r,
                "pearson_p": 1e-9,
                "pearson_ci": [r - 1e-3, r] if r is not None else None,
                "pearson_reason": None if r is not None else "undefined: constant",
            }
        return {
            "n_samples": 500,
            "axes": axes,
            "position_error_norm": {
                k: float(rng.uniform(0, 0.01))
                for k in ("mean", "median", "std", "min", "max", "rmse", "sse")
            },
            "counts": {"matched": 500, "masked": 0, "dropped": 0},
        }

    return {"topics": {"model_rov_pose": one(), "gui_camera_pose": one()}}


def _write_experiment(root: Path, runs: int) -> Path:
    """An experiment directory of real MCAP logs (50 Hz Gazebo / 60 Hz Unity, 10 s each)."""
    from uwval.frames import convert_arrays
    from uwval.io.mcap_io import McapPoseWriter
    from uwval.rotations import quat_from_rpy

    (root / "runs").mkdir(parents=True, exist_ok=True)
    manifest: dict[str, Any] = {"experiment": {"name": "bench"}, "runs": []}
    for i in range(runs):
        speed, lag = 0.5 + 0.25 * (i % 4), 0.01 * (1 + i // 4)
        tg, tu = np.arange(0, 10, 1 / 50), np.arange(0, 10, 1 / 60)

        def pose(ts: np.ndarray, speed: float = speed) -> tuple[np.ndarray, np.ndarray]:
            pos = np.stack([speed * ts, np.sin(ts), np.full_like(ts, -2.0)], axis=1)
            return pos, quat_from_rpy(np.stack([0 * ts, 0 * ts, 0.2 * ts], axis=1))

        pg, qg = pose(tg)
        pu, qu = convert_arrays(*pose(np.clip(tu - lag, 0, None)), "enu", "unity-flu")
        name = f"run{i:02d}"
        with McapPoseWriter(root / "runs" / f"{name}.mcap") as w:
            for topic in ("model_rov_pose", "gui_camera_pose"):
                w.write_poses(f"/gazebo/{topic}", (tg * 1e9).astype(np.int64), pg, qg, "enu")
                w.write_poses(f"/unity/{topic}", (tu * 1e9).astype(np.int64), pu, qu, "unity-flu")
        manifest["runs"].append(
            {
                "name": name,
                "log": f"runs/{name}.mcap",
                "factors": {"force": 5.0 * (1 + i % 4), "current": 0.1 * (i // 4)},
                "bridge": {"latency_mean_s": lag, "dropped": 0},
            }
        )
    (root / "manifest.json").write_text(json.dumps(manifest))
    return root


def _demo_results(root: Path) -> Path:
    """The default experiment's 54 runs simulated (``uwval simulate``) and compared into
    ``root/results/comparisons.json``, as ``uwval demo`` leaves them."""
    import subprocess

    from uwval.resources import data_path
    from uwval.results import compare_pending, load_experiment_results

    subprocess.run(
        [sys.executable, "-m", "uwval", "simulate", str(data_path("experiments", "default.toml")),
         "-o", str(root)],
        check=True,
        capture_output=True,
    )  # fmt: skip
    exp = compare_pending(load_experiment_results(root))
    runs = [
        {"name": r.name, "log": str(r.log), "factors": r.factors, "bridge": r.bridge,
         "comparison": r.comparison}
        for r in exp.runs
    ]  # fmt: skip
    (root / "results").mkdir(exist_ok=True)
    (root / "results" / "comparisons.json").write_text(json.dumps({"runs": runs, "failed": []}))
    return root


def _demo_rows(tmp: Path) -> list[BenchRow]:
    """`uwval report` of the 54-run demo: HTML alone and HTML + PDF (one run each after a
    warm-up: imports and font caches are not the report's cost)."""
    from uwval.reports import build_report

    exp = _demo_results(tmp / "demo")
    out = tmp / "demo-out"
    build_report(exp, out / "warm.html")
    rows = []
    for label, pdf, target in (("HTML", None, 6.0), ("HTML + PDF", out / "r.pdf", 10.0)):
        times = []
        for _ in range(2):
            outcome = build_report(exp, out / "r.html", pdf=pdf)
            times.append(sum(outcome.timings.values()))
        stages = ", ".join(f"{k} {v:.1f}" for k, v in outcome.timings.items())
        rows.append(
            BenchRow(
                f"report of the 54-run demo: {label}",
                median(times),
                "s",
                target=f"<= {target:g} s",
                met=median(times) <= target,
                notes=f"{outcome.n_runs} runs; stages (s): {stages}",
            )
        )
    return rows


def run(quick: bool = False) -> list[BenchRow]:
    from uwval.gate import check, load_thresholds
    from uwval.reports import build_report
    from uwval.resources import data_path
    from uwval.results import ResultsTable, anova_oneway

    rows: list[BenchRow] = []
    reps = 1 if quick else 3
    n_runs = 50 if quick else 500
    rng = np.random.default_rng(0)
    items = [
        (
            f"run{i:04d}",
            {"force": float(i % 4), "current": float(i % 3) / 10},
            _comparison_json(rng),
        )
        for i in range(n_runs)
    ]
    holder: dict[str, ResultsTable] = {}

    def build() -> None:
        holder["t"] = ResultsTable.from_comparisons(items)

    (t_build,) = alternate([build], reps=reps)
    table = holder["t"]
    rows.append(
        BenchRow(
            f"results table from {n_runs} run comparisons",
            median(t_build),
            "s",
            target="< 2 s for 500 runs",
            met=median(t_build) < 2.0 * n_runs / 500,
            notes=f"{len(table)} tidy rows",
        )
    )
    th = load_thresholds(data_path("thresholds", "default.toml"))
    (t_gate,) = alternate([lambda: check(table, th)], reps=reps)
    rows.append(
        BenchRow(
            f"gate: default thresholds on {n_runs} runs",
            median(t_gate),
            "s",
            target="< 2 s for 500 runs",
            met=median(t_gate) < 2.0 * n_runs / 500,
        )
    )
    (t_anova,) = alternate([lambda: anova_oneway(table, "force")], reps=reps)
    rows.append(
        BenchRow(
            f"one-way ANOVA per topic/axis, {n_runs} runs",
            median(t_anova),
            "s",
            target="< 1 s",
            met=median(t_anova) < 1.0,
        )
    )
    with tempfile.TemporaryDirectory() as tmp:
        exp = _write_experiment(Path(tmp) / "exp", 2 if quick else 8)
        out = Path(tmp) / "out"
        (t_html,) = alternate([lambda: build_report(exp, out / "r.html")], reps=1)
        size = (out / "r.html").stat().st_size / 2**20
        rows.append(
            BenchRow(
                f"HTML report, {2 if quick else 8} runs (compare + plots)",
                median(t_html),
                "s",
                target="< 30 s",
                met=median(t_html) < 30,
                notes=f"{size:.1f} MiB self-contained HTML",
            )
        )
        (t_both,) = alternate(
            [lambda: build_report(exp, out / "r.html", pdf=out / "r.pdf")], reps=1
        )
        rows.append(
            BenchRow(
                f"HTML + PDF report, {2 if quick else 8} runs",
                median(t_both),
                "s",
                target="< 45 s",
                met=median(t_both) < 45,
            )
        )
        if not quick:
            rows += _demo_rows(Path(tmp))
    return rows


if __name__ == "__main__":
    for r in run(quick="--quick" in sys.argv):
        print(
            f"{r.name:55s} {r.uwval:9.3f} {r.unit:4s} target {r.target:22s} met={r.met} {r.notes}"
        )
