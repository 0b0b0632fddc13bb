"""Build the validation report (HTML, optionally PDF) from a log or from experiment results.

``build_report(source, html_path, pdf=..., ...)`` accepts

* one log (MCAP, rosbag2 directory, ROS 1 bag): compared on the spot (vehicle + camera
  topics, ``uwval.comparison.compare_logs``), a one-run report;
* a results location (experiment directory with ``manifest.json``, a ``results/`` directory
  with ``comparisons.json`` or ``results.csv/json``, or one of those files): the experiment
  report.

The report answers first: the study's sentence (``analysis.json``), pass or fail per threshold
rule and per factor level, then the numbers (one format per quantity), the figures (each drawn
once and shared by the HTML and the PDF; per-run plots for the few worst runs only) and the
provenance. The verdict is the CI gate (:mod:`uwval.gate`) on the same results.
"""

from __future__ import annotations

import time
import warnings as warnings_module
from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

from uwval.errors import ConfigError
from uwval.gate import (
    GateInputError,
    GateResult,
    Thresholds,
    check,
    display_path,
    load_thresholds,
    require_integrity,
    resolve_input,
)
from uwval.reports import plots
from uwval.reports.answer import (
    ANALYSIS_FILE,
    ANALYSIS_SCHEMA,
    SENSITIVITY_FILE,
    SENSITIVITY_SCHEMA,
    analysis_section,
    find_study_file,
    sensitivity_section,
)
from uwval.reports.content import Plot, Report, Section, Table, Text
from uwval.reports.levels import RuleScope, level_table, rule_scopes, rules_table
from uwval.reports.method import method_line
from uwval.reports.numbers import (
    Quantity,
    fmt,
    fmt_correlation_interval,
    fmt_unit,
    to_shown,
)
from uwval.reports.sections import (
    _sha256,
    bridge_section,
    level_label,
    paper_section,
    provenance_section,
    roundoff_line,
    run_ids,
    runs_section,
    secondary_section,
    summary_section,
    two_way_section,
)
from uwval.results import (
    AXES,
    ExperimentResults,
    ResultsTable,
    RunRecord,
    compare_pending,
    load_experiment_results,
    roundoff_axes,
    topic_results,
)

LOG_SUFFIXES = (".mcap", ".bag", ".db3")
DEFAULT_THRESHOLDS = "default"
#: Runs with per-run plots by default: the worst few (a figure per run costs ~0.3 s).
DEFAULT_DETAIL_RUNS = 3

#: A progress report: (stage, seconds it took, or None when it starts).
ProgressFn = Callable[[str, float | None], None]


@dataclass
class ReportOutcome:
    """What :func:`build_report` wrote, and the gate verdict shown in it."""

    html: Path
    pdf: Path | None
    gate: GateResult | None
    table: ResultsTable
    n_runs: int
    warnings: list[str] = field(default_factory=list)
    #: Why the gate refused the results (missing integrity fields), or ''.
    refused: str = ""
    #: Seconds per stage, in order (for the progress lines and the benchmark).
    timings: dict[str, float] = field(default_factory=dict)


@dataclass
class _RunDetail:
    run: RunRecord
    pairs: dict[str, Any]  # topic -> ComparisonResult-like (plots.AlignedPair)
    error: str = ""
    why: str = ""  # why this run is shown (worst x, failing)


def is_log(path: Path) -> bool:
    """A single log (not a results location): MCAP/bag file or rosbag2 directory."""
    if path.is_file():
        return path.suffix.lower() in LOG_SUFFIXES
    return path.is_dir() and (path / "metadata.yaml").is_file()


def sha256_of(path: Path) -> str:
    """Hex SHA-256 of a file, or of a directory's files (sorted relative paths + contents)."""
    return _sha256(path)


def _resolve_thresholds(thresholds: Thresholds | str | Path | None) -> Thresholds | None:
    """Parsed thresholds; ``"default"`` is the embedded file (an error when it is missing:
    a report must not quietly lose its verdict)."""
    if thresholds is None or isinstance(thresholds, Thresholds):
        return thresholds
    return load_thresholds(resolve_input("thresholds", thresholds) or "")


def _pairs_of(log_comparison: Any) -> dict[str, Any]:
    """topic -> ComparisonResult of a LogComparison (or a lone ComparisonResult)."""
    results = getattr(log_comparison, "results", None)
    if isinstance(results, Mapping):
        return dict(results)
    if hasattr(log_comparison, "reference") and hasattr(log_comparison, "t"):
        return {"trajectory": log_comparison}
    raise ConfigError(f"cannot take per-topic results from a {type(log_comparison).__name__}")


class _Stages:
    """Times the stages of a build and tells ``progress`` when each starts and ends."""

    def __init__(self, progress: ProgressFn | None) -> None:
        self.progress = progress
        self.timings: dict[str, float] = {}

    @contextmanager
    def __call__(self, name: str) -> Iterator[None]:
        if self.progress is not None:
            self.progress(name, None)
        t0 = time.perf_counter()
        yield
        took = time.perf_counter() - t0
        self.timings[name] = took
        if self.progress is not None:
            self.progress(name, took)


def build_report(
    source: str | Path,
    html_path: str | Path,
    *,
    pdf: str | Path | None = None,
    manifest: str | Path | None = None,
    thresholds: Thresholds | str | Path | None = DEFAULT_THRESHOLDS,
    baseline: str | Path | ResultsTable | None = None,
    compare_options: Mapping[str, Any] | None = None,
    max_detail_runs: int = DEFAULT_DETAIL_RUNS,
    detail_topics: Sequence[str] | None = None,
    title: str = "uwval pose correspondence report",
    command: str = "",
    progress: ProgressFn | None = None,
) -> ReportOutcome:
    """Write the HTML report (and the PDF when ``pdf`` is given); return what was written.

    ``thresholds``: a TOML path, a parsed :class:`Thresholds`, ``"default"`` (the embedded
    defaults) or ``None`` (no threshold verdict); ``baseline``: a results file,
    ``"default"`` or a table. ``max_detail_runs``: the worst runs that get per-run plots
    (their logs are compared again for the aligned series). ``detail_topics`` limits those
    plots (default: the first, i.e. vehicle, topic). ``progress`` hears each stage.
    """
    src = Path(source)
    opts = dict(compare_options or {})
    warnings: list[str] = []
    stage = _Stages(progress)
    if not src.exists():
        raise ConfigError(f"{src}: no such log or results location")
    with stage("read the results"), warnings_module.catch_warnings(record=True) as caught:
        warnings_module.simplefilter("always")
        exp, single = _load(src, manifest, opts)
    # what the readers warned about (a truncated log, bytes lost) belongs in the report too
    for w in caught:
        if str(w.message) not in warnings:
            warnings.append(str(w.message))
        warnings_module.warn_explicit(w.message, w.category, w.filename, w.lineno)
    _plain_strings(exp.table)
    th = _resolve_thresholds(thresholds)
    base: ResultsTable | Path | None = (
        baseline if isinstance(baseline, ResultsTable) else resolve_input("baselines", baseline)
    )
    base_name = None if base is None or isinstance(base, ResultsTable) else str(base)
    with stage("gate"):
        gate, refused = _gate(exp, th, base, src)
    with stage("compare the worst runs again for their plots"):
        details = single or _worst_details(exp, gate, opts, max_detail_runs, warnings)
    with stage("compose"):
        report = _compose(
            _Inputs(exp, src, th, base_name, gate, refused, opts, warnings),
            details,
            title=title,
            command=command,
            detail_topics=detail_topics,
        )
    figs = [b for s in report.sections for b in s.blocks if isinstance(b, Plot)]
    with stage(f"draw {len(figs)} figures"):
        from uwval.reports.html import rasterize

        for p in figs:
            rasterize(p)
    html_out = Path(html_path)
    with stage("write HTML"):
        from uwval.reports.html import write_html

        write_html(report, html_out)
    pdf_out: Path | None = None
    if pdf is not None:
        with stage("write PDF"):
            from uwval.reports.pdf import write_pdf

            pdf_out = Path(pdf)
            write_pdf(report, pdf_out)
    plots.close(report.figures())
    return ReportOutcome(
        html_out, pdf_out, gate, exp.table, len(exp.runs), warnings, refused, stage.timings
    )


def _plain_strings(table: ResultsTable) -> None:
    """Hold the table's text columns as Python strings: the report walks them many times,
    and each walk over an Arrow-backed column converts every value again (a third of the
    composing time on a 54-run table)."""
    df = table.df
    for col in ("run", "topic", "axis", "metric", "unit", "note"):
        if col in df.columns and df[col].dtype != object:
            df[col] = df[col].astype(object)


def _load(
    src: Path, manifest: str | Path | None, opts: dict[str, Any]
) -> tuple[ExperimentResults, list[_RunDetail]]:
    """The results to report; for one log also its run detail (compared once, here)."""
    if is_log(src):
        from uwval.comparison import compare_logs

        lc = compare_logs(src, **opts)
        run = RunRecord(src.stem if src.is_file() else src.name, src, {}, {}, lc.to_json())
        table = ResultsTable.from_comparisons([(run.name, {}, run.comparison)])
        exp = ExperimentResults(table, [run], None, [src])
        return exp, [_RunDetail(run, _pairs_of(lc), why="the one run")]
    exp = load_experiment_results(src, manifest)
    if exp.table.df.empty and any(r.log is not None for r in exp.runs):
        exp = compare_pending(exp, opts)
    return exp, []


def _gate(
    exp: ExperimentResults,
    th: Thresholds | None,
    base: ResultsTable | Path | None,
    src: Path,
) -> tuple[GateResult | None, str]:
    """The gate's verdict, or None and why it refused the results (integrity fields)."""
    if th is None and base is None:
        return None, ""
    try:
        require_integrity(exp.table, [(r.name, r.comparison) for r in exp.runs], src)
    except GateInputError as exc:
        return None, str(exc)
    return check(exp.table, th, base, expected_runs=[r.name for r in exp.runs]), ""


def _failing_runs(gate: GateResult | None) -> dict[str, int]:
    out: dict[str, int] = {}
    for v in gate.violations if gate is not None else []:
        if v.run:
            out[v.run] = out.get(v.run, 0) + 1
    return out


def _worst_runs(table: ResultsTable, gate: GateResult | None, n: int) -> list[tuple[str, str]]:
    """(run, why) of the ``n`` runs worth a plot: failing runs first (most violations),
    then the largest position error of the first topic; one run per cell of the design (a
    replicate of a shown run would repeat its plots)."""
    if n <= 0 or table.df.empty:
        return []
    failing = _failing_runs(gate)
    topic = table.topics[0]
    norm = table.select(topic=topic, axis="position_norm", metric="max")
    worst = dict(zip(norm["run"], norm["value"].astype(float), strict=True))
    ranked = sorted(table.runs, key=lambda r: (-failing.get(r, 0), -worst.get(r, 0.0)))
    cells: dict[str, tuple[str, ...]] = {
        str(run): tuple(str(v) for v in row) for run, row in table.run_factors().iterrows()
    }
    seen: set[tuple[str, ...]] = set()
    picked = []
    for r in ranked:
        cell = cells.get(r, (r,)) if table.factors else (r,)
        if cell in seen and not failing.get(r):
            continue
        seen.add(cell)
        picked.append(r)
        if len(picked) == n:
            break
    out = []
    for r in picked:
        why = f"fails {failing[r]} check(s)" if failing.get(r) else ""
        if r in worst:
            extra = f"largest position error {fmt_unit(worst[r], Quantity.LENGTH)}"
            why = f"{why}; {extra}" if why else extra
        out.append((r, why))
    return out


def _worst_details(
    exp: ExperimentResults,
    gate: GateResult | None,
    opts: Mapping[str, Any],
    n: int,
    warnings: list[str],
) -> list[_RunDetail]:
    by_name = {r.name: r for r in exp.runs}
    chosen = _worst_runs(exp.table, gate, n)
    details = [_detail_for(by_name[r], opts, why) for r, why in chosen if r in by_name]
    if len(exp.runs) > len(details) and details:
        warnings.append(
            f"per-run plots shown for the {len(details)} worst of {len(exp.runs)} runs "
            "(--max-detail-runs)"
        )
    return details


def _detail_for(run: RunRecord, opts: Mapping[str, Any], why: str) -> _RunDetail:
    if run.log is None or not run.log.exists():
        return _RunDetail(run, {}, "log not available: plots need the aligned series", why)
    from uwval.comparison import compare_logs
    from uwval.errors import UwvalError

    try:
        return _RunDetail(run, _pairs_of(compare_logs(run.log, **opts)), why=why)
    except UwvalError as exc:
        return _RunDetail(run, {}, f"cannot compare {run.log}: {exc}", why)


# ----------------------------------------------------------------------------- composing
@dataclass(frozen=True)
class _Inputs:
    """What the sections are made from."""

    exp: ExperimentResults
    source: Path
    th: Thresholds | None
    baseline: str | None
    gate: GateResult | None
    refused: str
    options: Mapping[str, Any]
    warnings: list[str]


def _compose(
    inp: _Inputs,
    details: list[_RunDetail],
    *,
    title: str,
    command: str,
    detail_topics: Sequence[str] | None,
) -> Report:
    exp, gate, table = inp.exp, inp.gate, inp.exp.table
    now = datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M:%S UTC")
    if inp.refused:
        verdict = "REFUSED"
    else:
        verdict = "not checked" if gate is None else ("PASS" if gate.passed else "FAIL")
    sub = (
        f"{len(exp.runs)} run(s), topics: {', '.join(table.topics) or 'none'}; "
        f"factors: {', '.join(table.factors) or 'none'}"
    )
    method = method_line([r.comparison for r in exp.runs], inp.options)
    report = Report(title=title, subtitle=sub, verdict=verdict, generated=now, method=method)
    scopes = rule_scopes(table, inp.th) if inp.th is not None else []
    analysis = find_study_file(inp.source, ANALYSIS_FILE, ANALYSIS_SCHEMA)
    sensitivity = find_study_file(inp.source, SENSITIVITY_FILE, SENSITIVITY_SCHEMA)
    if analysis.doc is not None and analysis.doc.get("answer"):
        report.headline.append(str(analysis.doc["answer"]))
    report.headline.append(_verdict_sentence(inp, scopes))
    experiment = len(exp.runs) > 1 or bool(table.varying_factors())
    if experiment:
        report.sections.append(analysis_section(analysis))
    report.sections.append(_passfail_section(inp, scopes))
    if experiment:
        report.sections.append(sensitivity_section(sensitivity))
    for sec in (paper_section(table), summary_section(table), _levels_figures(table, scopes)):
        if sec is not None:
            report.sections.append(sec)
    for sec in (secondary_section(table), two_way_section(table)):
        if sec is not None:
            report.sections.append(sec)
    report.sections.append(runs_section(table, _failing_runs(gate)))
    report.sections += _detail_sections(details, detail_topics, scopes, full=len(exp.runs) == 1)
    for sec in (bridge_section(exp),):
        if sec is not None:
            report.sections.append(sec)
    report.sections.append(
        provenance_section(exp, inp.th, inp.baseline, inp.options, command, inp.source)
    )
    return report


def _verdict_sentence(inp: _Inputs, scopes: Sequence[RuleScope]) -> str:
    """The gate's answer in a sentence: which rules fail where, or the closest call."""
    gate = inp.gate
    if inp.refused:
        return f"REFUSED: {inp.refused}"
    if gate is None:
        return "Not gated: no thresholds or baseline were given."
    if gate.passed:
        close = [
            (s.worst()[0] / s.rule.max, s)
            for s in scopes
            if s.rule.max and s.worst()[0] == s.worst()[0]
        ]
        text = (
            f"PASS: every check holds in every run ({gate.checked} values"
            + (f", {len(scopes)} threshold rules" if scopes else "")
            + ")"
        )
        if close:
            ratio, s = max(close, key=lambda x: x[0])
            worst, run = s.worst()
            text += (
                f"; closest to its bound: {s.rule.label()} {fmt(worst, s.quantity)} of "
                f"{s.bound()} ({ratio * 100:.0f} %, run {run})"
            )
        return text + "."
    kinds = sorted({v.kind.value for v in gate.violations})
    parts = [_where_rule_fails(inp.exp.table, s, gate) for s in scopes]
    parts = [p for p in parts if p]
    return (
        f"FAIL: {len(gate.violations)} violation(s) among {gate.checked} values"
        + (f"; {'; '.join(parts)}" if parts else "")
        + f" (kinds: {', '.join(kinds)})."
    )


def _where_rule_fails(table: ResultsTable, scope: RuleScope, gate: GateResult) -> str:
    """ "vehicle x MAE fails only at current = 0.25 m/s (worst 3.78 of <= 3.00 mm)": the
    levels of each factor holding every failing run, when they are not all the levels."""
    label = scope.rule.label()
    bad_runs = {v.run for v in gate.violations if v.rule == label and v.run}
    if not bad_runs and not any(v.rule == label for v in gate.violations):
        return ""
    worst, _ = scope.worst(scope.rows[scope.rows["run"].isin(bad_runs)] if bad_runs else None)
    text = f"{label} fails"
    rf = table.run_factors()
    only = []
    for f in table.varying_factors():
        levels = rf[f].dropna().unique().tolist()
        failing = rf.loc[rf.index.isin(bad_runs), f].dropna().unique().tolist()
        if failing and len(failing) < len(levels):
            only.append(" or ".join(level_label(f, lv) for lv in sorted(failing)))
    if only:
        text += " only at " + ", ".join(only)
    return text + f" (worst {fmt(worst, scope.quantity)} of {scope.bound()})"


def _passfail_section(inp: _Inputs, scopes: Sequence[RuleScope]) -> Section:
    """Pass or fail per factor level and per rule, then what regressed, in detail."""
    gate = inp.gate
    sec = Section("verdict", "Pass or fail: per factor level and per threshold rule")
    if inp.refused:
        sec.blocks.append(Text(inp.refused, css="fail"))
    elif gate is None:
        sec.blocks.append(
            Text("No thresholds or baseline given: the results are not gated.", css="neutral")
        )
    else:
        head = gate.format(limit=0).splitlines()[0]
        sec.blocks.append(Text(head, css="pass" if gate.passed else "fail"))
        against = []
        if inp.th is not None:
            against.append(f"thresholds {display_path(inp.th.source)} ({len(inp.th.rules)} rules)")
        if inp.baseline is not None:
            against.append(f"baseline {display_path(inp.baseline)}")
        sec.blocks.append(
            Text("Checked against " + " and ".join(against or ["a baseline table"]) + ".")
        )
        lt = level_table(inp.exp.table, scopes, gate, inp.baseline is not None)
        if lt is not None:
            sec.blocks.append(lt)
        if scopes:
            sec.blocks.append(rules_table(scopes, gate, run_ids(inp.exp.table)))
        if gate.violations:
            sec.blocks.append(_violations_table(gate, run_ids(inp.exp.table)))
        if gate.skipped:
            more = [f"... {len(gate.skipped) - 10} more"] if len(gate.skipped) > 10 else []
            sec.blocks.append(Text([*gate.skipped[:10], *more], kind="list"))
    problems = [f"{f.get('name', '?')}: {f.get('error', '')}" for f in inp.exp.failed]
    if problems:
        sec.blocks.append(Text("Failed runs: ", css="fail"))
        sec.blocks.append(Text(problems, kind="list"))
    if inp.warnings:
        sec.blocks.append(Text(inp.warnings, kind="list"))
    run_warnings = inp.exp.run_warnings()
    if run_warnings:
        sec.blocks.append(Text("Warnings of the compared logs: ", css="fail"))
        sec.blocks.append(
            Text([f"{run}: {w}" for run, ws in run_warnings.items() for w in ws], kind="list")
        )
    return sec


def _violations_table(gate: GateResult, ids: Mapping[str, str]) -> Table:
    """Every violation (up to 200): where, the value against its bound, which rule."""
    from uwval.reports.numbers import quantity_of

    t = Table(
        "What regressed",
        ["run", "topic", "axis", "metric", "value", "bound", "kind: rule (note)"],
        [],
        caption="run: as labelled in the runs table (its factor levels are there).",
    )
    for v in gate.violations[:200]:
        q = quantity_of(v.metric, v.unit)
        unit = f" {'mm' if v.unit == 'm' else v.unit}" if v.unit else ""
        t.rows.append(
            [
                ids.get(v.run, v.run),
                v.topic,
                v.axis,
                v.metric,
                fmt(v.value, q) + unit,
                f"{v.op} {fmt(v.bound, q)}{unit}",
                f"{v.kind.value}: {v.rule}" + (f" ({v.note})" if v.note else ""),
            ]
        )
        t.flags[(len(t.rows) - 1, 4)] = "bad"
    if len(gate.violations) > 200:
        t.caption += f" First 200 of {len(gate.violations)} violations."
    return t


def _rule_bounds(
    scopes: Sequence[RuleScope], metric: str, topic: str
) -> dict[str, tuple[float, str]]:
    """Per axis group ("position", "rotation"): the tightest ``max`` bound of a rule on
    ``metric`` covering all of that group's axes for ``topic``, in shown units, labelled."""
    out: dict[str, tuple[float, str]] = {}
    groups = {"position": ("x", "y", "z"), "rotation": ("roll", "pitch", "yaw")}
    for kind, axes in groups.items():
        best: tuple[float, str] | None = None
        for s in scopes:
            r = s.rule
            if r.metric != metric or r.max is None or r.factors or not r.applies_to(topic):
                continue
            if not set(axes) & set(r.axes):
                continue
            shown = to_shown(r.max, s.quantity)
            if best is None or shown < best[0]:
                best = (shown, f"{r.label()} {s.bound()}")
        if best is not None:
            out[kind] = best
    return out


def _levels_figures(table: ResultsTable, scopes: Sequence[RuleScope]) -> Section | None:
    vary = table.varying_factors()
    if not vary:
        return None
    sec = Section("level-plots", "MAE per factor level, with the thresholds")
    skip = roundoff_axes(table)
    line = roundoff_line(skip)
    if line:
        sec.blocks.append(Text(line, css="neutral"))
    for topic in table.topics:
        fig = plots.level_means_figure(
            table, topic, vary, _rule_bounds(scopes, "mae", topic), skip.get(topic, ())
        )
        sec.blocks.append(
            Plot(
                f"MAE per level: {topic}",
                fig,
                "Dots: mean MAE over the runs at the level; bars: lowest to highest run; "
                "dashed red: the thresholds' MAE bound (named at the top when far above).",
            )
        )
    return sec


def _detail_sections(
    details: list[_RunDetail],
    topics: Sequence[str] | None,
    scopes: Sequence[RuleScope],
    *,
    full: bool,
) -> list[Section]:
    """Per-run tables and plots: the error over time (with the max-error bound) and the
    coloured trajectory; ``full`` (a one-run report, where they earn their time): also the
    overlay, per-axis series, histograms and the Unity-vs-Gazebo scatter."""
    out: list[Section] = []
    for d in details:
        run = d.run
        levels = ", ".join(level_label(k, v) for k, v in run.factors.items())
        sec = Section(
            f"run-{run.name}",
            f"Run {run.name}" + (f" ({levels})" if levels else ""),
            level=2,
            collapsed=len(out) >= 2,
        )
        if d.why:
            sec.blocks.append(Text(f"Shown because: {d.why}.", css="neutral"))
        if d.error:
            sec.blocks.append(Text(d.error, css="neutral"))
        per_topic = dict(topic_results(run.comparison)) if run.comparison else {}
        for topic, res in per_topic.items():
            sec.blocks.append(_run_metrics_table(topic, res))
        want = list(topics) if topics else list(d.pairs)[:1]
        for topic in want:
            pair = d.pairs.get(topic)
            if pair is None or len(pair.t) == 0:
                continue
            name = f"{run.name} / {topic}"
            if full:
                sec.blocks += _full_plots(pair, name, per_topic.get(topic, {}))
            sec.blocks.append(
                Plot(
                    f"Error over time: {name}",
                    plots.error_time_figure(pair, name, _rule_bounds(scopes, "max", topic)),
                    "Signed Unity - Gazebo per axis (mm, deg); dashed red: the thresholds' "
                    "max |error| bound at +- its value.",
                )
            )
            sec.blocks.append(
                Plot(
                    f"Trajectory coloured by the position error: {name}",
                    plots.trajectory_error_figure(pair, name, error_in_mm=True),
                    "Gazebo path from above (ENU x-y, m) coloured by |p_Unity - p_Gazebo| (mm); "
                    "Unity dashed grey (as evo_ape --plot_mode xy).",
                )
            )
        out.append(sec)
    return out


def _full_plots(pair: Any, name: str, res: Mapping[str, Any]) -> list[Plot]:
    """The one-run report's extra figures: overlay, per-axis series, histograms, scatter."""
    rs = {a: (res.get("axes", {}).get(a, {}) or {}).get("pearson_r") for a in AXES}
    return [
        Plot(
            f"Trajectory overlay: {name}",
            plots.trajectory_figure(pair, name),
            "ENU world: x east, y north, z up (m).",
        ),
        Plot(
            f"Per-axis series and error: {name}",
            plots.timeseries_figure(pair, name),
            "Left: both simulators; right: Unity - Gazebo (signed) and its absolute value.",
        ),
        Plot(
            f"Error histograms: {name}",
            plots.error_histogram_figure(pair, name),
            "Signed Unity - Gazebo per axis (m, deg), position-error norm (m) and rotation "
            "angle (deg); solid line: mean, dashed: RMSE.",
        ),
        Plot(
            f"Unity vs Gazebo: {name}",
            plots.scatter_figure(pair, rs, name),
            "Points on y = x mean perfect correspondence; r from the compare engine.",
        ),
    ]


def _run_metrics_table(topic: str, res: Mapping[str, Any]) -> Table:
    from uwval.reports.numbers import fmt as f
    from uwval.reports.sections import axis_quantity, shown_unit

    t = Table(
        f"{topic}: metrics per axis",
        [
            "axis",
            "unit",
            "MAE",
            "RMSE",
            "max |e|",
            "p95 |e|",
            "bias",
            "std",
            "Pearson r",
            "r 95% CI",
            "note",
        ],
        [],
    )
    for a in AXES:
        m = res.get("axes", {}).get(a, {})
        q = axis_quantity(a)
        ci = m.get("pearson_ci")
        ci_text = (
            fmt_correlation_interval(ci[0], ci[1])
            if isinstance(ci, (list, tuple)) and len(ci) == 2
            else "n/a"
        )
        t.rows.append(
            [
                a,
                shown_unit(a),
                *[f(m.get(k), q) for k in ("mae", "rmse", "max", "p95", "bias", "std")],
                f(m.get("pearson_r"), Quantity.CORRELATION),
                ci_text,
                str(m.get("pearson_reason") or ""),
            ]
        )
    n = res.get("n_samples")
    t.caption = f"{n} aligned samples" if n is not None else ""
    return t
