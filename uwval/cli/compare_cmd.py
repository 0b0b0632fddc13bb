"""``uwval compare`` and ``uwval doctor``: a thin CLI layer over :mod:`uwval.comparison`.

Imports of the engine happen inside the commands, so registering them costs nothing at
start-up, and the TUM ``--sync nearest`` path loads no pandas, scipy or matplotlib.
:func:`fast_compare` runs ``uwval compare`` without typer's per-parameter coercion layer
(which imports pydantic and builds a validator per option: ~0.1 s and ~15 MB per run).
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Annotated, Any

import typer

from uwval.cli import app
from uwval.cli.compare_run import (  # noqa: F401  (fast path re-exported for callers)
    _FAST_OPTIONS,
    _parse_offset,
    fast_compare,
    run_compare,
)

FRAME_HELP = (
    "Convention of the second (Unity) stream: unity-flu, unity-enu, ned, enu or auto "
    "(default: from the log's frame_id; enu for TUM files)"
)


@app.command("compare")
def compare_command(
    log_a: Annotated[Path, typer.Argument(help="Log (both sides) or the reference file")],
    log_b: Annotated[Path | None, typer.Argument(help="Second file: the Unity side")] = None,
    gazebo_topic: Annotated[str | None, typer.Option(help="Reference topic")] = None,
    unity_topic: Annotated[str | None, typer.Option(help="Other (Unity) topic")] = None,
    fmt: Annotated[
        str | None,
        typer.Option(
            "--format",
            help="Input format: tum, or a log format read by uwval.io (default: by suffix)",
        ),
    ] = None,
    frame: Annotated[str | None, typer.Option(help=FRAME_HELP)] = None,
    sync: Annotated[
        str,
        typer.Option(help="interp (lerp+slerp at reference stamps) or nearest (evo's association)"),
    ] = "interp",
    max_gap: Annotated[
        float | None,
        typer.Option(help="interp: mask samples in gaps longer than this (s; default 5 periods)"),
    ] = None,
    max_diff: Annotated[float, typer.Option(help="nearest: max stamp difference (s)")] = 0.01,
    offset: Annotated[
        str,
        typer.Option(
            help="Clock offset added to the second stream's stamps (s), or 'auto' to estimate it"
        ),
    ] = "0",
    max_offset: Annotated[float | None, typer.Option(help="Bound for --offset auto (s)")] = None,
    align: Annotated[str, typer.Option(help="none, se3, sim3 (Umeyama) or origin")] = "none",
    as_json: Annotated[bool, typer.Option("--json", help="Print the JSON result")] = False,
    output: Annotated[
        Path | None,
        typer.Option(
            "-o",
            "--output",
            help="Also write the JSON result here (with --batch: the results directory)",
        ),
    ] = None,
    batch: Annotated[
        bool,
        typer.Option(
            "--batch",
            help="LOG_A is an experiment directory or "
            "manifest: compare every log into one results table",
        ),
    ] = False,
    executor: Annotated[
        str, typer.Option(help="--batch: local (process pool), dask or inline")
    ] = "local",
    workers: Annotated[int | None, typer.Option(help="--batch: worker processes")] = None,
    scheduler: Annotated[str | None, typer.Option(help="--batch: Dask scheduler address")] = None,
    allow_protocol: Annotated[
        list[str] | None,
        typer.Option(
            "--allow-protocol",
            help="--batch: fetch manifest logs by this remote protocol (s3, gs, http...; "
            "repeatable; also UWVAL_ALLOW_PROTOCOLS=s3,gs). Without it only local paths are read",
        ),
    ] = None,
) -> None:
    """Compare the Gazebo and Unity pose streams: per-axis errors, Pearson r, evo's APE stats."""
    if batch:
        _batch(
            log_a,
            output,
            executor=executor,
            workers=workers,
            scheduler=scheduler,
            allow_protocols=allow_protocol or [],
            options={
                "gazebo_topic": gazebo_topic,
                "unity_topic": unity_topic,
                "fmt": fmt,
                "frame": frame,
                "sync": sync,
                "max_gap": max_gap,
                "max_diff": max_diff,
                "offset": _parse_offset(offset),
                "max_offset": max_offset,
                "align": align,
            },
        )
        return
    run_compare(
        log_a,
        log_b,
        gazebo_topic=gazebo_topic,
        unity_topic=unity_topic,
        fmt=fmt,
        frame=frame,
        sync=sync,
        max_gap=max_gap,
        max_diff=max_diff,
        offset=offset,
        max_offset=max_offset,
        align=align,
        as_json=as_json,
        output=output,
    )


def _batch(
    source: Path,
    output: Path | None,
    *,
    executor: str,
    workers: int | None,
    scheduler: str | None,
    options: dict[str, Any],
    allow_protocols: list[str],
) -> None:
    """``compare --batch``: every log of a sweep -> comparisons.json + the results table."""
    from rich.console import Console

    from uwval.batch import compare_batch

    console = Console()
    opts = {k: v for k, v in options.items() if v is not None}
    result = compare_batch(
        source,
        executor=executor,
        workers=workers,
        scheduler=scheduler,
        options=opts,
        allow_protocols=allow_protocols,
    )
    out = output or (source if source.is_dir() else source.parent) / "results"
    written = result.save(out)
    console.print(
        f"[green]compared {len(result.runs)} logs[/] -> " + ", ".join(str(p) for p in written)
    )
    for f in result.failed:
        console.print(f"[red]{f['name']} failed:[/] {f['error']}", highlight=False)
    if result.failed:
        raise typer.Exit(1)


@app.command("doctor")
def doctor_command(
    log_a: Annotated[Path, typer.Argument(help="Log holding both streams, or the reference file")],
    log_b: Annotated[Path | None, typer.Argument(help="Second file (the Unity side)")] = None,
    gazebo_topic: Annotated[str | None, typer.Option(help="Reference topic")] = None,
    unity_topic: Annotated[str | None, typer.Option(help="Other (Unity) topic")] = None,
    fmt: Annotated[str | None, typer.Option("--format", help="Input format (tum, ...)")] = None,
    frame: Annotated[
        str | None, typer.Option(help="The configured convention to check (default: from the log)")
    ] = None,
    offset: Annotated[str, typer.Option(help="Clock offset (s) or 'auto'")] = "0",
    as_json: Annotated[bool, typer.Option("--json", help="Print JSON")] = False,
) -> None:
    """Name the frame convention the Unity stream is really in (tries every signed axis map)."""
    from rich.console import Console
    from rich.markup import escape
    from rich.table import Table

    from uwval.comparison.logs import compare_logs

    result = compare_logs(
        log_a,
        log_b,
        gazebo_topic=gazebo_topic,
        unity_topic=unity_topic,
        fmt=fmt,
        frame=frame,
        offset=_parse_offset(offset),
        check_frame=True,
    )
    report = {
        name: (res.diagnosis.to_json() if res.diagnosis else None)
        for name, res in result.results.items()
    }
    if as_json:
        sys.stdout.write(json.dumps(report, indent=1, allow_nan=False) + "\n")
        return
    console = Console()
    for name, diag in report.items():
        if diag is None:
            console.print(f"{name}: too few overlapping samples to diagnose")
            continue
        table = Table(
            title=escape(f"{name}: configured {diag['configured']}"), title_justify="left"
        )
        for col in ("convention", "position RMS (m)", "rotation RMS (deg)", ""):
            table.add_column(col)
        for conv, sc in diag["scores"].items():
            mark = "best" if conv == diag["best"] else ""
            mark += " configured" if conv == diag["configured"] else ""
            table.add_row(
                conv, f"{sc['position_rms_m']:.4g}", f"{sc['rotation_rms_deg']:.4g}", mark.strip()
            )
        console.print(table)
        console.print(f"fitted world map: {diag['fitted_world_map']}")
        console.print(f"fitted body map:  {diag['fitted_body_map']}")
        if diag["best"]:
            console.print(
                f"the Unity stream is in [bold]{diag['best']}[/]: "
                f"{escape(diag['best_description'])}"
            )
        if diag["warning"]:
            console.print(f"[yellow]warning:[/] {escape(diag['warning'])}", highlight=False)
