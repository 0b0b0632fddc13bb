"""``uwval report`` (HTML/PDF report) and ``uwval check`` (the CI gate) commands."""

from __future__ import annotations

import json
import shlex
import sys
import time
import warnings
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import typer
from rich.console import Console
from rich.markup import escape

from uwval.cli import app
from uwval.cli.declare import Arg, Opt, declare_signature, given_options
from uwval.cli.notes import warnings_as_notes
from uwval.cli.shared_options import BASELINE, COMPARE_SUBSET, JSON, THRESHOLDS
from uwval.errors import ConfigError

# soft_wrap: lines are never cut at the terminal width (piped output is 80 columns wide to
# rich, and a wrapped verdict line defeats grep)
console = Console(soft_wrap=True)
err_console = Console(stderr=True, soft_wrap=True)

_OTHER_HELP = "Second file of a pair ({first} is then the reference), as compare"

#: Suffixes of one results file that is not a log: tables and JSON results.
_RESULT_SUFFIXES = (".json", ".csv", ".parquet")


#: The keywords of compare's options in report and check (what _compare_opts reads).
_COMPARE_KEYS = tuple(o.dest for o in COMPARE_SUBSET if o.dest != "config")


def _compare_opts(given: dict[str, Any], project: Any = None) -> dict[str, Any]:
    """The compare options the user typed (``given``, by keyword, as ``uwval compare``
    takes them), completed by the project file ``project``
    (:class:`uwval.config.ProjectConfig`)."""
    from uwval.comparison.options import parse_offset as _parse_offset
    from uwval.config import merged_options

    typed = {k: v for k, v in given.items() if k in _COMPARE_KEYS and v is not None}
    opts = merged_options(typed, project)
    if "max_diff" in typed and "sync" not in opts:  # as compare: evo's association
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


@dataclass(frozen=True)
class ReportOptions:
    """What one ``uwval report`` was asked: the input(s), the pages to write (HTML and
    PDF paths), the gate (thresholds and baseline as given), the per-run plots, and the
    compare options the user typed (by keyword, as :func:`_compare_opts` reads them)."""

    source: Path
    other: Path | None
    output: Path
    pdf: Path | None
    thresholds: str | None
    baseline: str | None
    manifest: Path | None
    max_detail_runs: int
    topics: tuple[str, ...] | None
    results_out: Path | None
    compare_given: dict[str, Any]
    config: Path | None


#: The options of ``uwval report``, in ``--help`` order.
REPORT_OPTIONS: tuple[Arg | Opt, ...] = (
    Arg(
        "source",
        Path,
        "A log (MCAP, rosbag2 dir, .bag) or results: an experiment directory "
        "(manifest.json), results/ (comparisons.json, results.csv) or a results file.",
    ),
    Arg("other", Path, _OTHER_HELP.format(first="SOURCE"), default=None),
    Opt("output", ("-o", "--output"), Path, Path("report.html"), "HTML file to write."),
    Opt("pdf", ("--pdf",), Path, None, "Also write this PDF (same content)."),
    THRESHOLDS,
    BASELINE,
    Opt("manifest", ("--manifest",), Path, None, "manifest.json, when not next to the results."),
    Opt(
        "max_detail_runs",
        ("--max-detail-runs",),
        int,
        3,
        "Runs with per-run plots: the worst ones (failing first).",
        (("min", 0),),
    ),
    Opt(
        "topic",
        ("--topic",),
        list[str],
        None,
        "Topic(s) with per-run plots (default: the vehicle topic).",
    ),
    Opt(
        "results_out",
        ("--results",),
        Path,
        None,
        "Also save the results table here (.csv/.json/.parquet or a dir).",
    ),
    *COMPARE_SUBSET,
)


def report(**kw: Any) -> None:
    """Write a self-contained HTML report (and optionally a PDF) of pose correspondence.

    SOURCE: an experiment or results location, one log, a saved ``uwval compare -o`` JSON,
    or a reference trajectory file with OTHER (as ``uwval compare gt.txt est.txt``).
    """
    given = given_options(kw.pop("ctx"), kw)
    topics = kw["topic"]
    options = ReportOptions(
        source=kw["source"],
        other=kw["other"],
        output=kw["output"],
        pdf=kw["pdf"],
        thresholds=kw["thresholds"],
        baseline=kw["baseline"],
        manifest=kw["manifest"],
        max_detail_runs=kw["max_detail_runs"],
        topics=tuple(topics) if topics else None,
        results_out=kw["results_out"],
        compare_given=given,
        config=kw["config"],
    )
    run_report(options)


declare_signature(report, REPORT_OPTIONS, context=True)
app.command(name="report")(report)


def _report_input(
    options: ReportOptions, opts: dict[str, Any], scratch: Path
) -> tuple[Path, dict[str, Any]]:
    """What the report builder reads, and the compare options of its plots: a single
    comparison (one log, a pair, a saved result) becomes a one-run comparisons.json
    under ``scratch``; an experiment or results location is read as it is."""
    source, other = options.source, options.other
    one = None
    if other is not None or _compare_json(source) is not None or not _is_log(source):
        one = _one_run(source, other, opts)
    if one is None:
        return source, opts
    name, doc, log = one
    where = scratch / "run" / "results"
    where.mkdir(parents=True)
    if log is None:  # a saved result: re-read its files for the plots, as compared
        # (the saved options, with only what the command line gives over them: a
        # project file's defaults must not redraw the plots under other options)
        log, saved_opts = _saved_inputs(doc)
        opts = {**saved_opts, **_compare_opts(options.compare_given, None)}
    elif other is not None:
        opts = {**opts, "path_b": other}  # the plots re-read the pair
    rec = {"name": name, "factors": {}, "comparison": doc, "log": str(log) if log else None}
    (where / "comparisons.json").write_text(json.dumps({"runs": [rec], "failed": []}))
    return where / "comparisons.json", opts


def run_report(options: ReportOptions) -> None:
    """Build the report of ``options`` and print where it went and its verdict."""
    import tempfile

    from uwval.config import load_config
    from uwval.reports import build_report

    project = load_config(options.config)
    opts = _compare_opts(options.compare_given, project)
    thresholds = options.thresholds
    if thresholds is None:  # the project file's, else the embedded defaults
        own = project.thresholds if project is not None else None
        thresholds = str(own) if own is not None else "default"
    th = None if thresholds.lower() == "none" else thresholds
    with tempfile.TemporaryDirectory(prefix="uwval-report-") as scratch:
        source_for_report, opts = _report_input(options, opts, Path(scratch))
        with _progress(str(options.source)) as progress, warnings.catch_warnings():
            # build_report collects what the readers warned about into outcome.warnings
            warnings.simplefilter("ignore")
            outcome = build_report(
                source_for_report,
                options.output,
                pdf=options.pdf,
                manifest=options.manifest,
                thresholds=th,
                baseline=options.baseline,
                compare_options=opts,
                max_detail_runs=options.max_detail_runs,
                detail_topics=options.topics,
                command=shlex.join(["uwval", *sys.argv[1:]]),
                progress=progress,
            )
    if options.results_out is not None:
        import uwval

        outcome.table.meta.update(
            {
                "uwval_version": uwval.__version__,
                "source": str(options.source),
                "command": shlex.join(["uwval", *sys.argv[1:]]),
            }
        )
        outcome.table.save(options.results_out)
    _print_outcome(outcome)


def _print_outcome(outcome: Any) -> None:
    """The report's notes and its summary line '... (N run(s)); verdict X (in T s)'
    (``outcome``: :class:`uwval.reports.ReportOutcome`)."""
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


@dataclass(frozen=True)
class CheckOptions:
    """What one ``uwval check`` was asked: the results (or log, pair, saved result), the
    gate (thresholds and baseline as given), how to print the verdict (JSON; at most
    ``limit`` violations, 0 = all), a baseline to write instead of checking, and the
    compare options the user typed (by keyword, as :func:`_compare_opts` reads them)."""

    results: Path
    other: Path | None
    thresholds: str | None
    baseline: str | None
    as_json: bool
    limit: int
    write_baseline: Path | None
    compare_given: dict[str, Any]
    config: Path | None


#: The options of ``uwval check``, in ``--help`` order.
CHECK_OPTIONS: tuple[Arg | Opt, ...] = (
    Arg(
        "results",
        Path,
        "Results: experiment dir, results/ dir, results.csv/json or comparisons.json; "
        "or one log, a saved `uwval compare -o` JSON, or a trajectory file with OTHER.",
    ),
    Arg("other", Path, _OTHER_HELP.format(first="RESULTS"), default=None),
    THRESHOLDS,
    BASELINE,
    JSON,
    Opt(
        "limit",
        ("--limit",),
        int,
        200,
        "Violations listed at most (0 = all).",
        (("min", 0),),
    ),
    Opt(
        "write_baseline",
        ("--write-baseline",),
        Path,
        None,
        "Write these results as a golden baseline (JSON/CSV) instead of checking.",
    ),
    *COMPARE_SUBSET,
)


def check(**kw: Any) -> None:
    """CI gate: exit 1 and list what regressed when a threshold or the baseline is broken.

    Exit codes: 0 pass, 1 regression, 2 bad input (unreadable results or thresholds).
    """
    given = given_options(kw.pop("ctx"), kw)
    options = CheckOptions(
        results=kw["results"],
        other=kw["other"],
        thresholds=kw["thresholds"],
        baseline=kw["baseline"],
        as_json=kw["as_json"],
        limit=kw["limit"],
        write_baseline=kw["write_baseline"],
        compare_given=given,
        config=kw["config"],
    )
    run_check_command(options)


declare_signature(check, CHECK_OPTIONS, context=True)
app.command(name="check")(check)


def run_check_command(options: CheckOptions) -> None:
    """Gate the results of ``options`` (or write their baseline); exit 1 on a regression."""
    from uwval.config import load_config
    from uwval.gate import check as run_check
    from uwval.gate import require_integrity, resolve_input
    from uwval.results import compare_pending, load_experiment_results

    project = load_config(options.config)
    thresholds, baseline = options.thresholds, options.baseline
    results, write_baseline = options.results, options.write_baseline
    if thresholds is None and project is not None and project.thresholds is not None:
        thresholds = str(project.thresholds)
    elif thresholds is not None and thresholds.lower() == "none":  # no threshold verdict
        thresholds = None
    th_path = resolve_input("thresholds", thresholds)
    base_path = resolve_input("baselines", baseline)
    if thresholds is None and baseline is None and write_baseline is None:
        raise ConfigError(
            "uwval check needs --thresholds FILE.toml and/or --baseline FILE.json "
            "(or thresholds = ... in uwval.toml)"
        )
    opts = _compare_opts(options.compare_given, project)
    one = _one_run(results, options.other, opts)
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
    if options.as_json:
        typer.echo(json.dumps(verdict.to_json(), indent=1))
    else:  # the verdict is the command's output: stdout, PASS or FAIL alike
        text = verdict.format(limit=None if options.limit == 0 else options.limit)
        console.print(text, highlight=False, soft_wrap=True, markup=False)
    if exp.failed:
        err_console.print(
            f"{len(exp.failed)} run(s) failed to simulate or compare: "
            + ", ".join(str(f.get("name")) for f in exp.failed),
            markup=False,
        )
    if not verdict.passed or exp.failed:
        raise typer.Exit(1)
