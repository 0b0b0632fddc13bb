"""``uwval demo``: the default experiment end to end, into ``./uwval-demo/``.

simulate (factorial: force x torque x current, two levels each) -> TCP bridge -> Unity-like
client -> MCAP logs -> batch compare -> results table -> HTML (+ PDF) report -> CI gate
against the golden baseline. Every stage is the same code the individual commands run.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Annotated, Any

import typer
from rich.console import Console
from rich.table import Table

from uwval.cli import app
from uwval.cli.console import output_console
from uwval.cli.pipeline import SessionOptions
from uwval.cli.simulate_cmd import run_experiment
from uwval.resources import data_path

console = Console()


@app.command()
def demo(
    output: Annotated[Path, typer.Option("-o", "--output", help="Output directory.")] = Path(
        "uwval-demo"
    ),
    experiment: Annotated[
        Path | None, typer.Option(help="Experiment TOML (default: embedded).")
    ] = None,
    workers: Annotated[
        int | None, typer.Option(help="Worker processes (default: all cores).")
    ] = None,
    pdf: Annotated[bool, typer.Option(help="Also write report.pdf.")] = True,
) -> None:
    """Run the embedded default experiment end to end: logs, results, report, verdict."""
    from uwval.batch import compare_batch

    exp = experiment or data_path("experiments", "default.toml")
    t0 = time.perf_counter()
    console.rule(f"[bold]uwval demo[/]: {exp.name} -> {output}/")
    manifest = run_experiment(exp, output, SessionOptions(), workers=workers)
    console.print(
        f"[green]simulated[/] {len(manifest['runs'])} runs "
        f"({manifest['wall_time_s']:.1f} s): logs in {output / 'runs'}"
    )
    for f in manifest["failed"]:
        console.print(f"[red]run {f['name']} failed:[/] {f['error']}")
    batch = compare_batch(output, workers=workers)
    results_dir = output / "results"
    batch.save(results_dir)
    console.print(f"[green]compared[/] {len(batch.runs)} logs: results in {results_dir}")
    _print_summary(batch.runs)
    console.print(f"full results table (every metric and axis): {results_dir / 'results.csv'}")

    from uwval.reports import build_report

    html = output / "report.html"
    pdf_path = output / "report.pdf" if pdf else None
    with console.status("writing the HTML" + (" and PDF" if pdf_path else "") + " report..."):
        build_report(results_dir, html, pdf=pdf_path, manifest=output / "manifest.json")
    console.print(f"[green]report[/] {html}" + (f" and {pdf_path}" if pdf_path else ""))

    from uwval.gate import check_results, load_thresholds

    verdict = check_results(
        batch.table, thresholds=load_thresholds(data_path("thresholds", "default.toml"))
    )
    console.print(verdict.render())
    console.print(f"demo finished in {time.perf_counter() - t0:.1f} s")
    if manifest["failed"] or batch.failed or not verdict.passed:
        raise typer.Exit(1)


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
    output_console().print(table)  # a file or a pipe: the full width, no cell cut to "1.2e-…"
