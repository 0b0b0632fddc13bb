"""``uwval compare`` and ``uwval doctor``: a thin typer layer over :mod:`uwval.comparison`.

The command builds one :class:`uwval.comparison.options.CompareOptions`
(:func:`uwval.cli.compare_args.compare_options`), calls
:func:`uwval.comparison.logs.run_comparison`, and prints or writes the typed result.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

import typer

from uwval.cli import app
from uwval.cli.compare_args import COMPARE_OPTIONS, EvoCommand, compare_options
from uwval.cli.console import error_console, output_console, warn
from uwval.cli.declare import Arg, Opt, declare_signature, given_options
from uwval.cli.shared_options import (
    FORMAT,
    FRAME,
    GAZEBO_TOPIC,
    JSON,
    OFFSET,
    RESULT_FILE,
    UNITY_TOPIC,
)
from uwval.comparison.logs import LogComparison
from uwval.comparison.options import CompareOptions
from uwval.errors import ConfigError

#: Options of one comparison that --batch refuses (one line, exit 2), by keyword.
_SINGLE_RUN_ONLY = {
    "pose_relation": "--pose_relation",
    "plot": "--plot",
    "save_plot": "--save_plot",
    "save_errors": "--save-errors",
    "save_results": "--save_results",
    "html": "--html",
    "change_unit": "--change_unit",
    "logfile": "--logfile",
}
#: Options that belong to --batch only.
_BATCH_ONLY = ("results_dir", "executor", "workers", "scheduler", "allow_protocol")


#: The positional words of ``compare``.
_WORDS = Arg(
    "words",
    list[str],
    "LOG (both sides), REF EST (two files), LOG /ref_topic /other_topic; "
    "evo's shapes: tum|kitti|euroc REF EST, bag|bag2 LOG /ref_topic /other_topic",
    metavar="INPUTS",
    show_default=False,
)


def compare_command(**kwargs: Any) -> None:
    """Compare the Gazebo and Unity pose streams: per-axis errors, Pearson r, evo's APE stats."""
    given = given_options(kwargs.pop("ctx"), kwargs)
    if kwargs["batch"]:
        _batch(kwargs, given)
        return
    for key in _BATCH_ONLY:
        if key in given:
            raise ConfigError(f"--{key.replace('_', '-')} applies to --batch only")
    from uwval.cli.notes import warnings_as_notes
    from uwval.comparison.logs import run_comparison
    from uwval.config import load_config

    options = compare_options(given, load_config(kwargs["config"]))
    _check_outputs(kwargs)
    with warnings_as_notes():
        result = run_comparison(options)
    _emit(result, options, kwargs)


declare_signature(compare_command, (_WORDS, *COMPARE_OPTIONS), context=True)
app.command("compare", cls=EvoCommand)(compare_command)


def _check_outputs(kwargs: dict[str, Any]) -> None:
    """Refuse output names that cannot work before the (possibly long) comparison runs."""
    html = kwargs["html"]
    if html is not None and html.suffix.lower() not in (".html", ".htm"):
        raise ConfigError(f"--html {html}: the page's name must end in .html")


def how_compared(result: LogComparison) -> str:
    """The sync and alignment that made the numbers, for titles and pages."""
    doc = result.vehicle.stats
    sync = doc["sync"]
    text = f"sync {sync['method']}"
    if sync["method"] == "nearest":
        text += f" (max diff {sync.get('max_diff_s', 0.01):g} s)"
    return f"{text}, align {doc['alignment']['mode']}, frame {doc['frame']['configured']}"


def _emit(result: LogComparison, options: CompareOptions, kwargs: dict[str, Any]) -> None:
    """Write the files asked for, then print the JSON or the tables (unless --silent)."""
    from uwval.cli.compare_files import (
        errors_csv,
        label_paths,
        save_results_zip,
        write_html,
        write_output,
        write_plots,
    )

    text = json.dumps(result.to_json(), indent=1, allow_nan=False)
    saved: list[Path] = []
    if kwargs["output"] is not None:
        write_output(kwargs["output"], text + "\n", "the JSON result")
        saved.append(kwargs["output"])
    results_path: Path | None = kwargs["save_results"]
    if results_path is not None:
        if results_path.suffix.lower() == ".zip":
            relation = options.ape_relation or "trans_part"
            data, reason = save_results_zip(result, str(relation))
            write_output(results_path, data, "the results")
            if reason is not None:
                warn(
                    f"{results_path} is not an evo result ({reason}): written without evo's "
                    "stats.json/info.json, so evo_res refuses it; --sync nearest (and the "
                    "streams in ENU) give one evo_res can mix with its own"
                )
        else:
            write_output(results_path, text + "\n", "the results")
        saved.append(results_path)
    if kwargs["save_errors"] is not None:
        for name, path in label_paths(
            kwargs["save_errors"], list(result.results), result.primary
        ).items():
            write_output(path, errors_csv(result.results[name]), "the per-sample errors")
            saved.append(path)
    if kwargs["plot"] or kwargs["save_plot"] is not None:
        saved += write_plots(result, kwargs["save_plot"])
    if kwargs["html"] is not None:
        saved.append(write_html(result, kwargs["html"], how_compared(result)))
    _print(result, text, saved, kwargs)


def _print(result: LogComparison, text: str, saved: list[Path], kwargs: dict[str, Any]) -> None:
    """stdout: the JSON alone (--json) or the tables and the files written; --silent
    prints nothing there; --logfile gets the same text."""
    if kwargs["as_json"]:
        if not kwargs["silent"]:
            sys.stdout.write(text + "\n")
        for path in saved:  # stdout holds the JSON alone
            error_console().print(f"wrote {path}", markup=False, highlight=False)
        return
    import io

    from uwval.cli.compare_table import print_comparison

    logfile: Path | None = kwargs["logfile"]
    console = output_console(
        file=io.StringIO() if kwargs["silent"] else None, record=logfile is not None
    )
    print_comparison(console, result)
    if kwargs["verbose"]:
        _print_alignments(console, result)
    for path in saved:
        console.print(f"wrote {path}", markup=False, highlight=False)
    if logfile is not None:
        from uwval.cli.compare_files import write_output

        write_output(logfile, console.export_text(), "the log file")


def _print_alignments(console: Any, result: LogComparison) -> None:
    """evo's -v: the alignment of each topic pair (scale, translation, rotation)."""
    import numpy as np

    for name, res in result.results.items():
        al = res.alignment
        if al.mode == "none":
            continue
        console.print(
            f"{name}: alignment {al.mode}: scale {al.scale:.9g}, translation (m) "
            f"{np.array2string(al.translation, precision=9)}, rotation\n"
            f"{np.array2string(al.rotation, precision=9)}",
            markup=False,
            highlight=False,
        )


def _batch(kwargs: dict[str, Any], given: dict[str, Any]) -> None:
    """``compare --batch``: every log of a sweep -> comparisons.json + the results table."""
    from uwval.batch import compare_batch
    from uwval.cli.compare_args import align_mode, sync_method

    if kwargs["config"] is not None:
        raise ConfigError(
            "--config applies to one comparison; --batch takes its options from the command line"
        )
    for key, flag in _SINGLE_RUN_ONLY.items():
        if kwargs.get(key):
            raise ConfigError(f"{flag} applies to one comparison, not to --batch")
    words = list(kwargs["words"])
    if len(words) != 1:
        raise ConfigError("--batch takes one experiment directory or manifest")
    source = Path(words[0])
    out_dir: Path | None = kwargs["results_dir"]
    if kwargs["output"] is not None:
        if out_dir is not None:
            raise ConfigError("--batch: give the results folder once (--results-dir)")
        warn("with --batch, -o as the results folder is deprecated: use --results-dir")
        out_dir = kwargs["output"]
    options = _batch_options(
        kwargs, given, align_mode(given).value, sync_method(given, "max_diff" in given)
    )
    result = compare_batch(
        source,
        executor=kwargs["executor"],
        workers=kwargs["workers"],
        scheduler=kwargs["scheduler"],
        allow_protocols=kwargs["allow_protocol"] or [],
        options=options,
    )
    out = out_dir or (source if source.is_dir() else source.parent) / "results"
    written = result.save(out)
    console = output_console()
    console.print(
        f"[green]compared {len(result.runs)} logs[/] -> " + ", ".join(str(p) for p in written)
    )
    for f in result.failed:
        console.print(f"[red]{f['name']} failed:[/] {f['error']}", highlight=False)
    if result.failed:
        raise typer.Exit(1)


def _batch_options(
    kwargs: dict[str, Any], given: dict[str, Any], align: str, sync: Any
) -> dict[str, Any]:
    """The compare keywords each run of a batch gets (uwval.batch passes them to
    compare_logs): what the user gave, checked as for one comparison."""
    from uwval.comparison.options import ClockOffset

    out: dict[str, Any] = {
        "align": align,
        "offset": ClockOffset.parse(kwargs["offset"]).engine_value(),
        "max_diff": kwargs["max_diff"],
    }
    if sync is not None:
        out["sync"] = sync.value
    for key in ("gazebo_topic", "unity_topic", "fmt", "frame", "max_gap", "max_offset", "drift"):
        if kwargs[key] is not None:
            out[key] = kwargs[key]
    if kwargs["n_to_align"] != -1:
        out["n_to_align"] = kwargs["n_to_align"]
    return out


#: The options of ``uwval doctor``, in ``--help`` order.
DOCTOR_OPTIONS: tuple[Arg | Opt, ...] = (
    Arg("log_a", Path, "Log holding both streams, or the reference file"),
    Arg("log_b", Path, "Second file (the Unity side)", default=None),
    GAZEBO_TOPIC,
    UNITY_TOPIC,
    FORMAT,
    FRAME,
    OFFSET,
    JSON,
    RESULT_FILE,
)


def doctor_command(**kw: Any) -> None:
    """Name the frame convention the Unity stream is really in (tries every signed axis map)."""
    from uwval.cli.compare_args import choice
    from uwval.cli.compare_files import write_output
    from uwval.comparison.logs import run_comparison
    from uwval.comparison.options import ClockOffset, CompareInputs, InputFormat

    fmt = kw["fmt"]
    inputs = CompareInputs(
        kw["log_a"],
        kw["log_b"],
        kw["gazebo_topic"],
        kw["unity_topic"],
        choice(InputFormat, fmt, "--format") if fmt else None,
    )
    offset = ClockOffset.parse(kw["offset"])
    options = CompareOptions(inputs, frame=kw["frame"], offset=offset, check_frame=True)
    result = run_comparison(options)
    report = {
        name: (res.diagnosis.to_json() if res.diagnosis else None)
        for name, res in result.results.items()
    }
    text = json.dumps(report, indent=1, allow_nan=False)
    if kw["output"] is not None:
        write_output(kw["output"], text + "\n", "the JSON result")
    if kw["as_json"]:
        sys.stdout.write(text + "\n")
        return
    _print_diagnoses(report)


declare_signature(doctor_command, DOCTOR_OPTIONS)
app.command("doctor")(doctor_command)


def _print_diagnoses(report: dict[str, Any]) -> None:
    """The doctor's table per topic pair: every convention's residuals, the best one."""
    from rich.markup import escape
    from rich.table import Table

    console = output_console()
    for name, diag in report.items():
        if diag is None:
            console.print(f"{name}: too few overlapping samples to diagnose")
            continue
        table = Table(
            title=escape(f"{name}: configured {diag['configured']}"), title_justify="left"
        )
        for col in ("convention", "position RMS (m)", "rotation RMS (deg)", ""):
            table.add_column(col, no_wrap=True)
        for conv, sc in diag["scores"].items():
            mark = "best" if conv == diag["best"] else ""
            mark += " configured" if conv == diag["configured"] else ""
            table.add_row(
                conv, f"{sc['position_rms_m']:.4g}", f"{sc['rotation_rms_deg']:.4g}", mark.strip()
            )
        console.print(table)
        console.print(f"fitted world map: {diag['fitted_world_map']}", markup=False)
        console.print(f"fitted body map:  {diag['fitted_body_map']}", markup=False)
        if diag["best"]:
            console.print(
                f"the Unity stream is in [bold]{diag['best']}[/]: "
                f"{escape(diag['best_description'])}"
            )
        if diag["warning"]:
            console.print(f"[yellow]warning:[/] {escape(diag['warning'])}", highlight=False)
