"""``uwval demo``: the default experiment end to end, into ``./uwval-demo/``.

simulate (factorial: force x torque x current) -> TCP bridge -> Unity-like client -> MCAP logs
-> batch compare -> results table, analysis.json, sensitivity.json -> HTML (+ PDF) report ->
CI gate against the golden baseline. Every stage is the library code the individual commands
run (:func:`uwval.bridge.experiment.run_experiment`, :func:`uwval.batch.compare_batch`, ...).
"""

from __future__ import annotations

import sys
import time
from pathlib import Path
from typing import Annotated, Any

import typer
from rich.console import Console
from rich.table import Table

from uwval.bridge.experiment import SimulateOptions, resolve_experiment, run_experiment
from uwval.cli import app
from uwval.cli.shared_options import WORKERS

console = Console()


@app.command()
def demo(
    output: Annotated[Path, typer.Option("-o", "--output", help="Output directory.")] = Path(
        "uwval-demo"
    ),
    experiment: Annotated[
        str | None,
        typer.Option(help="Experiment TOML or an embedded experiment's name (default: default)."),
    ] = None,
    workers: Annotated[int | None, typer.Option(*WORKERS.flags, help=WORKERS.help)] = None,
    pdf: Annotated[bool, typer.Option(help="Also write report.pdf.")] = True,
) -> None:
    """Run the embedded default experiment end to end: logs, results, report, verdict."""
    from uwval.batch import compare_batch

    exp = resolve_experiment(experiment or "default")
    t0 = time.perf_counter()
    console.rule(f"[bold]uwval demo[/]: {exp.name} -> {output}/")
    sim = run_experiment(
        SimulateOptions(output=output, experiment=exp, workers=workers, progress=True)
    )
    console.print(
        f"[green]simulated[/] {len(sim.runs)} runs ({sim.wall_time_s:.1f} s): logs in "
        f"{sim.out_dir / 'runs'}"
    )
    for f in sim.failed:
        console.print(f"[red]run {f['name']} failed:[/] {f['error']}")
    batch = compare_batch(sim.out_dir, workers=workers)
    results_dir = sim.out_dir / "results"
    batch.save(results_dir)
    console.print(f"[green]compared[/] {len(batch.runs)} logs: results in {results_dir}")
    _print_summary(batch.runs)
    console.print(f"full results table (every metric and axis): {results_dir / 'results.csv'}")
    _write_study_files(batch.table, exp, results_dir)

    from uwval.reports import build_report

    html = sim.out_dir / "report.html"
    pdf_path = sim.out_dir / "report.pdf" if pdf else None
    with console.status("writing the HTML" + (" and PDF" if pdf_path else "") + " report..."):
        build_report(results_dir, html, pdf=pdf_path, manifest=sim.manifest_path)
    console.print(f"[green]report[/] {html}" + (f" and {pdf_path}" if pdf_path else ""))

    from uwval.gate import check_results, load_thresholds
    from uwval.resources import data_path

    verdict = check_results(
        batch.table, thresholds=load_thresholds(data_path("thresholds", "default.toml"))
    )
    console.print(verdict.render())
    console.print(f"demo finished in {time.perf_counter() - t0:.1f} s")
    if not sim.ok or batch.failed or not verdict.passed:
        raise typer.Exit(1)


def _write_study_files(table: Any, experiment: Path, results_dir: Path) -> None:
    """analysis.json (the factorial analysis) and sensitivity.json (how far the choice of
    the Gazebo model moves the pose) beside the results."""
    from uwval.results.analysis import write_analysis
    from uwval.simulator import load_experiment
    from uwval.simulator.sensitivity import model_sensitivity, write_sensitivity

    console.print(f"[green]analysis[/] {write_analysis(table, results_dir / 'analysis.json')}")
    exp = load_experiment(experiment)
    report = model_sensitivity(exp.vehicle, duration_s=exp.duration_s, baseline=exp.model)
    path = write_sensitivity(report, results_dir / "sensitivity.json")
    console.print(f"[green]sensitivity[/] of the pose to the Gazebo model: {path}")


def _table_console() -> Console:
    """stdout for the table: the terminal's width, or unwrapped into a file or a pipe (rich
    would otherwise cut cells at 80 columns)."""
    if sys.stdout.isatty():
        return Console()
    return Console(width=100_000, soft_wrap=True, force_terminal=False)


def _print_summary(runs: list[dict[str, Any]]) -> None:
    """Per run: factor levels, vehicle position/yaw MAE, Pearson r and max position error."""
    from rich import box

    table = Table(
        title="vehicle pose, Unity vs Gazebo (per run)", box=box.SIMPLE_HEAD, pad_edge=False
    )
    factor_names = sorted({k for r in runs for k in r["factors"]})
    table.add_column("run", no_wrap=True)
    units = {"force": "N", "torque": "N m", "current": "m/s"}
    for name in factor_names:
        table.add_column(f"{name} {units.get(name, '')}".strip(), justify="right", no_wrap=True)
    for col in ("MAE x m", "MAE yaw deg", "r x", "max |e| m"):
        table.add_column(col, justify="right", no_wrap=True)
    for i, r in enumerate(runs):
        c = r["comparison"]
        axes = c["axes"]
        rx = axes["x"]["pearson_r"]
        table.add_row(
            f"{i:02d}",
            *[f"{r['factors'].get(k, '')}" for k in factor_names],
            f"{axes['x']['mae']:.2e}",
            f"{axes['yaw']['mae']:.2e}",
            "n/a" if rx is None else f"{rx:.5f}",
            f"{c['position_error_norm']['max']:.2e}",
        )
    _table_console().print(table)
