"""``uwval report`` (HTML/PDF report) and ``uwval check`` (the CI gate) commands."""

from __future__ import annotations

import json
import shlex
import sys
import warnings
from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console
from rich.markup import escape

from uwval.cli import app
from uwval.cli.notes import warnings_as_notes
from uwval.errors import ConfigError

console = Console()
err_console = Console(stderr=True)


@app.command()
def report(
    source: Annotated[
        Path,
        typer.Argument(
            help="A log (MCAP, rosbag2 dir, .bag) or results: an experiment directory "
            "(manifest.json), results/ (comparisons.json, results.csv) or a results file."
        ),
    ],
    output: Annotated[Path, typer.Option("-o", "--output", help="HTML file to write.")] = Path(
        "report.html"
    ),
    pdf: Annotated[Path | None, typer.Option(help="Also write this PDF (same content).")] = None,
    thresholds: Annotated[
        str,
        typer.Option(
            help="Thresholds TOML for the verdict; 'default' = embedded, 'none' = no verdict."
        ),
    ] = "default",
    baseline: Annotated[
        Path | None, typer.Option(help="Golden results JSON/CSV to gate on.")
    ] = None,
    manifest: Annotated[
        Path | None, typer.Option(help="manifest.json, when not next to the results.")
    ] = None,
    max_detail_runs: Annotated[int, typer.Option(help="Runs with per-run plots.", min=0)] = 8,
    topic: Annotated[
        list[str] | None,
        typer.Option(help="Topic(s) with per-run plots (default: the vehicle topic)."),
    ] = None,
    gazebo_topic: Annotated[str | None, typer.Option(help="Reference topic (single log).")] = None,
    unity_topic: Annotated[str | None, typer.Option(help="Unity topic (single log).")] = None,
    results_out: Annotated[
        Path | None,
        typer.Option(
            "--results", help="Also save the results table here (.csv/.json/.parquet or a dir)."
        ),
    ] = None,
) -> None:
    """Write a self-contained HTML report (and optionally a PDF) of pose correspondence."""
    from uwval.reports import build_report

    opts = {
        k: v
        for k, v in (("gazebo_topic", gazebo_topic), ("unity_topic", unity_topic))
        if v is not None
    }
    th = None if thresholds.lower() == "none" else thresholds
    with console.status(f"building the report of {source}..."), warnings.catch_warnings():
        # build_report collects what the readers warned about into outcome.warnings
        warnings.simplefilter("ignore")
        outcome = build_report(
            source,
            output,
            pdf=pdf,
            manifest=manifest,
            thresholds=th,
            baseline=baseline,
            compare_options=opts,
            max_detail_runs=max_detail_runs,
            detail_topics=topic,
            command=shlex.join(["uwval", *sys.argv[1:]]),
        )
    if results_out is not None:
        import uwval

        outcome.table.meta.update(
            {
                "uwval_version": uwval.__version__,
                "source": str(source),
                "command": shlex.join(["uwval", *sys.argv[1:]]),
            }
        )
        outcome.table.save(results_out)
    for w in outcome.warnings:
        console.print(f"[yellow]note:[/] {escape(w)}")
    verdict = (
        "not checked"
        if outcome.gate is None
        else ("[green]PASS[/]" if outcome.gate.passed else "[red]FAIL[/]")
    )
    console.print(
        f"[green]wrote[/] {outcome.html}"
        + (f" and {outcome.pdf}" if outcome.pdf else "")
        + f" ({outcome.n_runs} run(s)); verdict {verdict}"
    )


@app.command()
def check(
    results: Annotated[
        Path,
        typer.Argument(
            help="Results: experiment dir, results/ dir, results.csv/json or comparisons.json."
        ),
    ],
    thresholds: Annotated[Path | None, typer.Option(help="Thresholds TOML (see docs).")] = None,
    baseline: Annotated[
        Path | None, typer.Option(help="Golden baseline (results JSON/CSV).")
    ] = None,
    json_out: Annotated[bool, typer.Option("--json", help="Print the verdict as JSON.")] = False,
    limit: Annotated[int, typer.Option(help="Violations listed at most (0 = all).", min=0)] = 200,
    write_baseline: Annotated[
        Path | None,
        typer.Option(
            help="Write these results as a golden baseline (JSON/CSV) instead of checking."
        ),
    ] = None,
) -> None:
    """CI gate: exit 1 and list what regressed when a threshold or the baseline is broken.

    Exit codes: 0 pass, 1 regression, 2 bad input (unreadable results or thresholds).
    """
    from uwval.gate import check as run_check
    from uwval.results import compare_pending, load_experiment_results

    if thresholds is None and baseline is None and write_baseline is None:
        raise ConfigError("uwval check needs --thresholds FILE.toml and/or --baseline FILE.json")
    exp = load_experiment_results(results)
    if exp.table.df.empty and any(r.log is not None for r in exp.runs):
        with console.status(f"comparing {len(exp.runs)} logs of {results}..."), warnings_as_notes():
            exp = compare_pending(exp)
    if exp.table.df.empty:
        raise ConfigError(f"{results}: no compared results and no logs to compare")
    if write_baseline is not None:
        import uwval
        from uwval.gate import baseline_from

        golden = baseline_from(
            exp.table,
            meta={
                "uwval_version": uwval.__version__,
                "source": str(results),
                "command": shlex.join(["uwval", *sys.argv[1:]]),
                "regenerate": "uwval simulate data/experiments/default.toml -o DIR && "
                "uwval check DIR --write-baseline data/baselines/default.json",
            },
        )
        written = golden.save(write_baseline)
        console.print(
            f"[green]wrote[/] baseline {', '.join(map(str, written))} "
            f"({len(golden.runs)} runs, {len(golden)} values)"
        )
        if exp.failed:
            raise typer.Exit(1)
        return
    verdict = run_check(exp.table, thresholds, baseline, expected_runs=[r.name for r in exp.runs])
    if json_out:
        typer.echo(json.dumps(verdict.to_json(), indent=1))
    else:
        text = verdict.format(limit=None if limit == 0 else limit)
        (console if verdict.passed else err_console).print(
            text, highlight=False, soft_wrap=True, markup=False
        )
    if exp.failed:
        err_console.print(
            f"{len(exp.failed)} run(s) failed to simulate or compare: "
            + ", ".join(str(f.get("name")) for f in exp.failed),
            markup=False,
        )
    if not verdict.passed or exp.failed:
        raise typer.Exit(1)
