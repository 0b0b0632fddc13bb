"""``uwval report`` (HTML/PDF report) and ``uwval check`` (the CI gate) commands."""

from __future__ import annotations

import json
import shlex
import sys
import time
import warnings
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Annotated, Any

import typer
from rich.console import Console
from rich.markup import escape

from uwval.cli import app
from uwval.cli.notes import warnings_as_notes
from uwval.errors import ConfigError

# soft_wrap: lines are never cut at the terminal width (piped output is 80 columns wide to
# rich, and a wrapped verdict line defeats grep)
console = Console(soft_wrap=True)
err_console = Console(stderr=True, soft_wrap=True)

#: Suffixes of one results file that is not a log: tables and JSON results.
_RESULT_SUFFIXES = (".json", ".csv", ".parquet")


#: Compare's options as ``report`` and ``check`` take them (one log, a pair, a saved result).
FormatOpt = Annotated[
    str | None, typer.Option("--format", help="Input format (tum, kitti, euroc...), as compare")
]
FrameOpt = Annotated[str | None, typer.Option(help="Convention of the second stream, as compare")]
SyncOpt = Annotated[str | None, typer.Option(help="interp or nearest, as compare")]
MaxDiffOpt = Annotated[
    float | None,
    typer.Option(
        "--max-diff",
        "--t-max-diff",
        "--t_max_diff",
        help="nearest: max dt (s); without --sync it means nearest",
    ),
]
OffsetOpt = Annotated[
    str | None, typer.Option("--offset", "--t_offset", help="Clock offset (s) or 'auto'")
]
AlignOpt = Annotated[str | None, typer.Option(help="none, se3, sim3, origin or scale, as compare")]
ConfigOpt = Annotated[
    Path | None,
    typer.Option(help="Project file: pairs, frames, thresholds (default: ./uwval.toml)"),
]


def _compare_opts(
    gazebo_topic: str | None,
    unity_topic: str | None,
    fmt: str | None,
    frame: str | None,
    sync: str | None,
    max_diff: float | None,
    offset: str | None,
    align: str | None,
    project: Any = None,
) -> dict[str, Any]:
    """The compare options given on the command line (as ``uwval compare`` takes them),
    completed by the project file ``project`` (:class:`uwval.config.ProjectConfig`)."""
    from uwval.comparison.options import parse_offset as _parse_offset
    from uwval.config import merged_options

    given: dict[str, Any] = {
        "gazebo_topic": gazebo_topic,
        "unity_topic": unity_topic,
        "fmt": fmt,
        "frame": frame,
        "sync": sync,
        "max_diff": max_diff,
        "offset": offset,
        "align": align,
    }
    opts = merged_options({k: v for k, v in given.items() if v is not None}, project)
    if max_diff is not None and "sync" not in opts:  # as compare: evo's association
        opts["sync"] = "nearest"
    opts.pop("pose_relation", None)  # compare's printout only: not part of the results
    if "offset" in opts:
        opts["offset"] = _parse_offset(str(opts["offset"]))
    return opts


def _compare_json(path: Path) -> dict[str, Any] | None:
    """The result of ``uwval compare -o`` / ``--json`` in ``path``, or None if it is not one."""
    if path.suffix.lower() != ".json" or not path.is_file():
        return None
    try:
        obj = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError):
        return None  # not ours to judge: the results loader gives its own error
    if isinstance(obj, dict) and "axes" in obj and "runs" not in obj:
        return obj
    return None


def _saved_inputs(doc: dict[str, Any]) -> tuple[Path | None, dict[str, Any]]:
    """The files and compare options of a saved ``uwval compare -o`` result, so that its
    report can plot the aligned series again: (first file or None, options). None when a
    file is gone (the report then says that the plots need the log)."""
    sources = [Path(str(p)) for p in doc.get("sources") or []]
    if not sources or len(sources) > 2 or not all(p.exists() for p in sources):
        return None, {}
    sync = doc.get("sync") or {}
    opts: dict[str, Any] = {
        "sync": sync.get("method", "interp"),
        "offset": float((doc.get("offset") or {}).get("applied_s") or 0.0),
        "align": (doc.get("alignment") or {}).get("mode", "none"),
    }
    if sync.get("method") == "nearest" and sync.get("max_diff_s") is not None:
        opts["max_diff"] = float(sync["max_diff_s"])
    frame = doc.get("frame") or {}
    if frame.get("source") in ("argument", "auto"):
        opts["frame"] = frame.get("configured")
    if len(sources) == 2:
        opts["path_b"] = sources[1]
    if all(_is_log(p) for p in sources) and doc.get("topics") and len(doc["topics"]) == 1:
        opts["gazebo_topic"] = (doc.get("reference") or {}).get("topic")
        opts["unity_topic"] = (doc.get("other") or {}).get("topic")
    return sources[0], {k: v for k, v in opts.items() if v is not None}


def _one_run(
    source: Path, other: Path | None, opts: dict[str, Any]
) -> tuple[str, dict[str, Any], Path | None] | None:
    """A single comparison to report or gate: (run name, compare JSON, log to re-read for
    the plots), when ``source`` is one log, a trajectory file (with ``other``) or a saved
    compare result; None for results locations (experiment or results directory, tables)."""
    from uwval.comparison import compare_logs

    saved = _compare_json(source)
    if saved is not None:
        if other is not None:
            raise ConfigError(f"{other}: a saved compare result ({source}) takes no second file")
        return source.stem, saved, None
    is_results = source.is_dir() and not (source / "metadata.yaml").is_file()
    if other is None and (is_results or source.suffix.lower() in _RESULT_SUFFIXES):
        return None
    with warnings_as_notes():
        lc = compare_logs(source, other, **opts)
    return source.stem if source.is_file() else source.name, lc.to_json(), source


def _is_log(path: Path) -> bool:
    """One log file or rosbag2 directory (as the report builder reads them)."""
    from uwval.reports.builder import is_log

    return is_log(path)


@contextmanager
def _progress(what: str) -> Iterator[Callable[[str, float | None], None]]:
    """Report progress per stage: a live status line on a terminal (rich), one plain line
    per finished stage when piped (a CI log shows where the time went)."""
    started = time.perf_counter()
    if console.is_terminal:
        with console.status(f"report of {what}: starting") as status:

            def live(stage: str, took: float | None) -> None:
                if took is None:
                    status.update(f"report of {escape(what)}: {escape(stage)}...")

            yield live
        return

    def plain(stage: str, took: float | None) -> None:
        if took is not None:
            total = time.perf_counter() - started
            console.print(
                f"report: {stage}: {took:.1f} s (total {total:.1f} s)",
                markup=False,
                highlight=False,
            )

    yield plain


@app.command()
def report(
    source: Annotated[
        Path,
        typer.Argument(
            help="A log (MCAP, rosbag2 dir, .bag) or results: an experiment directory "
            "(manifest.json), results/ (comparisons.json, results.csv) or a results file."
        ),
    ],
    other: Annotated[
        Path | None,
        typer.Argument(help="Second file of a pair (SOURCE is then the reference), as compare"),
    ] = None,
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
        str | None,
        typer.Option(help="Golden results JSON/CSV to gate on; 'default' = embedded."),
    ] = None,
    manifest: Annotated[
        Path | None, typer.Option(help="manifest.json, when not next to the results.")
    ] = None,
    max_detail_runs: Annotated[
        int, typer.Option(help="Runs with per-run plots: the worst ones (failing first).", min=0)
    ] = 3,
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
    fmt: FormatOpt = None,
    frame: FrameOpt = None,
    sync: SyncOpt = None,
    max_diff: MaxDiffOpt = None,
    offset: OffsetOpt = None,
    align: AlignOpt = None,
    config: ConfigOpt = None,
) -> None:
    """Write a self-contained HTML report (and optionally a PDF) of pose correspondence.

    SOURCE: an experiment or results location, one log, a saved ``uwval compare -o`` JSON,
    or a reference trajectory file with OTHER (as ``uwval compare gt.txt est.txt``).
    """
    import tempfile

    from uwval.config import load_config
    from uwval.reports import build_report

    project = load_config(config)
    opts = _compare_opts(
        gazebo_topic, unity_topic, fmt, frame, sync, max_diff, offset, align, project
    )
    if thresholds == "default" and project is not None and project.thresholds is not None:
        thresholds = str(project.thresholds)
    th = None if thresholds.lower() == "none" else thresholds
    scratch = tempfile.TemporaryDirectory(prefix="uwval-report-")
    one = None
    if other is not None or _compare_json(source) is not None or not _is_log(source):
        one = _one_run(source, other, opts)
    if one is not None:  # one comparison: reported as a one-run comparisons.json
        name, doc, log = one
        where = Path(scratch.name) / "run" / "results"
        where.mkdir(parents=True)
        if log is None:  # a saved result: re-read its files for the plots, as compared
            # (the saved options, with only what the command line gives over them: a
            # project file's defaults must not redraw the plots under other options)
            log, saved_opts = _saved_inputs(doc)
            given = _compare_opts(
                gazebo_topic, unity_topic, fmt, frame, sync, max_diff, offset, align, None
            )
            opts = {**saved_opts, **given}
        elif other is not None:
            opts["path_b"] = other  # the plots re-read the pair
        rec = {"name": name, "factors": {}, "comparison": doc, "log": str(log) if log else None}
        (where / "comparisons.json").write_text(json.dumps({"runs": [rec], "failed": []}))
        source_for_report = where / "comparisons.json"
    else:
        source_for_report = source
    with scratch, _progress(str(source)) as progress, warnings.catch_warnings():
        # build_report collects what the readers warned about into outcome.warnings
        warnings.simplefilter("ignore")
        outcome = build_report(
            source_for_report,
            output,
            pdf=pdf,
            manifest=manifest,
            thresholds=th,
            baseline=baseline,
            compare_options=opts,
            max_detail_runs=max_detail_runs,
            detail_topics=topic,
            command=shlex.join(["uwval", *sys.argv[1:]]),
            progress=progress,
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
    if outcome.refused:
        verdict = "[red]REFUSED[/] (" + escape(outcome.refused) + ")"
    elif outcome.gate is None:
        verdict = "not checked"
    else:
        verdict = "[green]PASS[/]" if outcome.gate.passed else "[red]FAIL[/]"
    took = sum(outcome.timings.values())
    console.print(
        f"[green]wrote[/] {escape(str(outcome.html))}"
        + (f" and {escape(str(outcome.pdf))}" if outcome.pdf else "")
        + f" ({outcome.n_runs} run(s)); verdict {verdict} (in {took:.1f} s)"
    )


@app.command()
def check(
    results: Annotated[
        Path,
        typer.Argument(
            help="Results: experiment dir, results/ dir, results.csv/json or comparisons.json; "
            "or one log, a saved `uwval compare -o` JSON, or a trajectory file with OTHER."
        ),
    ],
    other: Annotated[
        Path | None,
        typer.Argument(help="Second file of a pair (RESULTS is then the reference), as compare"),
    ] = None,
    thresholds: Annotated[
        str | None,
        typer.Option(help="Thresholds TOML (see docs); 'default' = the embedded defaults."),
    ] = None,
    baseline: Annotated[
        str | None,
        typer.Option(help="Golden baseline (results JSON/CSV); 'default' = embedded."),
    ] = None,
    json_out: Annotated[bool, typer.Option("--json", help="Print the verdict as JSON.")] = False,
    limit: Annotated[int, typer.Option(help="Violations listed at most (0 = all).", min=0)] = 200,
    write_baseline: Annotated[
        Path | None,
        typer.Option(
            help="Write these results as a golden baseline (JSON/CSV) instead of checking."
        ),
    ] = None,
    gazebo_topic: Annotated[str | None, typer.Option(help="Reference topic (one log).")] = None,
    unity_topic: Annotated[str | None, typer.Option(help="Unity topic (one log).")] = None,
    fmt: FormatOpt = None,
    frame: FrameOpt = None,
    sync: SyncOpt = None,
    max_diff: MaxDiffOpt = None,
    offset: OffsetOpt = None,
    align: AlignOpt = None,
    config: ConfigOpt = None,
) -> None:
    """CI gate: exit 1 and list what regressed when a threshold or the baseline is broken.

    Exit codes: 0 pass, 1 regression, 2 bad input (unreadable results or thresholds).
    """
    from uwval.config import load_config
    from uwval.gate import check as run_check
    from uwval.gate import require_integrity, resolve_input
    from uwval.results import compare_pending, load_experiment_results

    project = load_config(config)
    if thresholds is None and project is not None and project.thresholds is not None:
        thresholds = str(project.thresholds)
    th_path = resolve_input("thresholds", thresholds)
    base_path = resolve_input("baselines", baseline)
    if thresholds is None and baseline is None and write_baseline is None:
        raise ConfigError(
            "uwval check needs --thresholds FILE.toml and/or --baseline FILE.json "
            "(or thresholds = ... in uwval.toml)"
        )
    opts = _compare_opts(
        gazebo_topic, unity_topic, fmt, frame, sync, max_diff, offset, align, project
    )
    one = _one_run(results, other, opts)
    if one is not None:  # one log, a pair of files or a saved compare result
        from uwval.results import ExperimentResults, ResultsTable, RunRecord

        name, doc, log = one
        table = ResultsTable.from_comparisons([(name, {}, doc)])
        exp = ExperimentResults(table, [RunRecord(name, log, {}, {}, doc)], None, [results])
    else:
        exp = load_experiment_results(results)
    if one is None and exp.table.df.empty and any(r.log is not None for r in exp.runs):
        with console.status(f"comparing {len(exp.runs)} logs of {results}..."), warnings_as_notes():
            exp = compare_pending(exp, opts)
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
                "regenerate": "uwval simulate default -o DIR && "
                "uwval check DIR --write-baseline baseline.json",
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
    require_integrity(exp.table, [(r.name, r.comparison) for r in exp.runs], results)
    verdict = run_check(exp.table, th_path, base_path, expected_runs=[r.name for r in exp.runs])
    if json_out:
        typer.echo(json.dumps(verdict.to_json(), indent=1))
    else:  # the verdict is the command's output: stdout, PASS or FAIL alike
        text = verdict.format(limit=None if limit == 0 else limit)
        console.print(text, highlight=False, soft_wrap=True, markup=False)
    if exp.failed:
        err_console.print(
            f"{len(exp.failed)} run(s) failed to simulate or compare: "
            + ", ".join(str(f.get("name")) for f in exp.failed),
            markup=False,
        )
    if not verdict.passed or exp.failed:
        raise typer.Exit(1)
