"""``uwval compare`` and ``uwval doctor``: a thin CLI layer over :mod:`uwval.comparison`.

Imports of the engine happen inside the commands, so registering them costs nothing at
start-up, and the TUM ``--sync nearest`` path loads no pandas, scipy or matplotlib.
:func:`fast_compare` runs ``uwval compare`` without typer's per-parameter coercion layer
(which imports pydantic and builds a validator per option: ~0.1 s and ~15 MB per run).
The options of ``compare`` are declared once, in :data:`uwval.cli.compare_run.COMPARE_OPTIONS`;
the typer command below is built from that table, as is the fast parser.
"""

from __future__ import annotations

import inspect
import json
import sys
from pathlib import Path
from typing import Annotated, Any, Optional

import typer

from uwval.cli import app
from uwval.cli.compare_run import (  # noqa: F401  (fast path re-exported for callers)
    _FAST_OPTIONS,
    COMPARE_OPTIONS,
    _align_mode,
    _parse_offset,
    fast_compare,
    run_compare,
)
from uwval.errors import ConfigError

#: Options of one comparison that --batch refuses (one line, exit 2), by keyword.
_SINGLE_RUN_ONLY = {
    "pose_relation": "--pose_relation",
    "plot": "--plot",
    "save_plot": "--save_plot",
    "save_errors": "--save-errors",
    "save_results": "--save_results",
    "html": "--html",
}


def _compare_parameters() -> list[inspect.Parameter]:
    """The typer signature of ``compare``: two arguments, then :data:`COMPARE_OPTIONS`."""
    kw = inspect.Parameter.KEYWORD_ONLY
    params = [
        inspect.Parameter("ctx", kw, annotation=typer.Context),
        inspect.Parameter(
            "log_a",
            kw,
            annotation=Annotated[
                Path, typer.Argument(help="Log (both sides) or the reference file")
            ],
        ),
        inspect.Parameter(
            "log_b",
            kw,
            default=None,
            annotation=Annotated[
                Optional[Path],  # noqa: UP045  (a runtime object: typer reads it)
                typer.Argument(help="Second file: the Unity side"),
            ],
        ),
    ]
    for o in COMPARE_OPTIONS:
        kind: Any = o.kind if o.default is not None else Optional[o.kind]  # noqa: UP045
        params.append(
            inspect.Parameter(
                o.dest,
                kw,
                default=o.default,
                annotation=Annotated[kind, typer.Option(*o.flags, help=o.help)],
            )
        )
    return params


def compare_command(**kwargs: Any) -> None:
    """Compare the Gazebo and Unity pose streams: per-axis errors, Pearson r, evo's APE stats."""
    ctx = kwargs.pop("ctx")
    batch_keys = {o.dest for o in COMPARE_OPTIONS if not o.fast}
    opts = {k: v for k, v in kwargs.items() if k not in batch_keys}
    log_a, log_b = opts.pop("log_a"), opts.pop("log_b")
    if kwargs["batch"]:
        output = opts.pop("output")
        opts.pop("as_json")
        opts.pop("verbose")
        if opts.pop("config") is not None:
            raise ConfigError(
                "--config applies to one comparison; --batch takes its options from the "
                "command line"
            )
        opts["align"] = _align_mode(
            opts["align"],
            opts.pop("evo_align"),
            opts.pop("correct_scale"),
            opts.pop("align_origin"),
        )
        if opts["n_to_align"] == -1:
            opts.pop("n_to_align")
        for key, flag in _SINGLE_RUN_ONLY.items():
            if opts.pop(key):
                raise ConfigError(f"{flag} applies to one comparison, not to --batch")
        opts["offset"] = _parse_offset(opts["offset"])
        _batch(
            log_a,
            output,
            executor=kwargs["executor"],
            workers=kwargs["workers"],
            scheduler=kwargs["scheduler"],
            allow_protocols=kwargs["allow_protocol"] or [],
            options=opts,
        )
        return
    # only what the user gave (not typer's defaults), so that uwval.toml fills the rest; an
    # option given with its default value (--offset 0) is still given
    given = {
        k: v
        for k, v in opts.items()
        if getattr(ctx.get_parameter_source(k), "name", "DEFAULT") != "DEFAULT"
    }
    run_compare(log_a, log_b, **given)


_signature = inspect.Signature(_compare_parameters(), return_annotation=None)
compare_command.__signature__ = _signature  # type: ignore[attr-defined]
compare_command.__annotations__ = {p.name: p.annotation for p in _signature.parameters.values()} | {
    "return": None
}
app.command("compare")(compare_command)


def _batch(
    source: Path,
    output: Path | None,
    *,
    executor: str,
    workers: int | None,
    scheduler: str | None,
    allow_protocols: list[str],
    options: dict[str, Any],
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
        allow_protocols=allow_protocols,
        options=opts,
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
