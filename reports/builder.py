"""Build the validation report (HTML, optionally PDF) from a log or from experiment results.

``build_report(source, html_path, pdf=..., ...)`` accepts

* one log (MCAP, rosbag2 directory, ROS 1 bag): compared on the spot (vehicle + camera
  topics, ``uwval.comparison.compare_logs``), a one-run report;
* a results location (experiment directory with ``manifest.json``, a ``results/`` directory
  with ``comparisons.json`` or ``results.csv/json``, or one of those files): the experiment
  report with per-factor sections. Per-run plots need the aligned series, so each run's log
  is compared again when it is on disk (at most ``max_detail_runs`` runs).

The verdict is the CI gate (:mod:`uwval.gate`) run on the same results: thresholds
(default: the embedded ``data/thresholds/default.toml``) and/or a golden baseline.

Size: one module on purpose: it only assembles one :class:`Report` from results, the gate
verdict and per-run comparisons; rendering lives in html/pdf, figures in plots.
"""

from __future__ import annotations

import hashlib
import platform
import sys
import warnings as warnings_module
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, cast

import numpy as np
import pandas as pd

from uwval.errors import ConfigError
from uwval.gate import GateResult, Thresholds, check, load_thresholds
from uwval.reports import plots
from uwval.reports.content import (
    Plot,
    Report,
    Section,
    Table,
    Text,
    fmt_interval,
    fmt_num,
    fmt_r,
)
from uwval.results import (
    AXES,
    AXIS_UNITS,
    ROUNDOFF_FLOOR,
    ExperimentResults,
    ResultsTable,
    RunRecord,
    anova_oneway,
    compare_pending,
    factor_label,
    factor_levels,
    load_experiment_results,
    roundoff_axes,
    summarize_by_level,
    two_way_pairs,
    two_way_table,
)

LOG_SUFFIXES = (".mcap", ".bag", ".db3")
DEFAULT_THRESHOLDS = "default"


@dataclass
class ReportOutcome:
    """What :func:`build_report` wrote, and the gate verdict shown in it."""

    html: Path
    pdf: Path | None
    gate: GateResult | None
    table: ResultsTable
    n_runs: int
    warnings: list[str] = field(default_factory=list)


@dataclass
class _RunDetail:
    run: RunRecord
    pairs: dict[str, Any]  # topic -> ComparisonResult-like (plots.AlignedPair)
    error: str = ""


def is_log(path: Path) -> bool:
    """A single log (not a results location): MCAP/bag file or rosbag2 directory."""
    if path.is_file():
        return path.suffix.lower() in LOG_SUFFIXES
    return path.is_dir() and (path / "metadata.yaml").is_file()


def sha256_of(path: Path) -> str:
    """Hex SHA-256 of a file, or of a directory's files (sorted relative paths + contents)."""
    h = hashlib.sha256()
    files = [path] if path.is_file() else sorted(p for p in path.rglob("*") if p.is_file())
    for f in files:
        if path.is_dir():
            h.update(str(f.relative_to(path)).encode() + b"\0")
        with open(f, "rb") as fh:
            while chunk := fh.read(1 << 20):
                h.update(chunk)
    return h.hexdigest()


def _resolve_thresholds(thresholds: Thresholds | str | Path | None) -> Thresholds | None:
    if thresholds is None or isinstance(thresholds, Thresholds):
        return thresholds
    if str(thresholds) == DEFAULT_THRESHOLDS:
        from uwval.resources import data_path

        try:
            return load_thresholds(data_path("thresholds", "default.toml"))
        except ConfigError:
            return None
    return load_thresholds(thresholds)


def _pairs_of(log_comparison: Any) -> dict[str, Any]:
    """topic -> ComparisonResult of a LogComparison (or a lone ComparisonResult)."""
    results = getattr(log_comparison, "results", None)
    if isinstance(results, Mapping):
        return dict(results)
    if hasattr(log_comparison, "reference") and hasattr(log_comparison, "t"):
        return {"trajectory": log_comparison}
    raise ConfigError(f"cannot take per-topic results from a {type(log_comparison).__name__}")


def build_report(
    source: str | Path,
    html_path: str | Path,
    *,
    pdf: str | Path | None = None,
    manifest: str | Path | None = None,
    thresholds: Thresholds | str | Path | None = DEFAULT_THRESHOLDS,
    baseline: str | Path | ResultsTable | None = None,
    compare_options: Mapping[str, Any] | None = None,
    max_detail_runs: int = 2,
    detail_topics: Sequence[str] | None = None,
    title: str = "uwval pose correspondence report",
    command: str = "",
) -> ReportOutcome:
    """Write the HTML report (and the PDF when ``pdf`` is given); return what was written.

    ``thresholds``: a TOML path, a parsed :class:`Thresholds`, ``"default"`` (embedded
    defaults when present) or ``None`` (no threshold verdict). ``detail_topics`` limits the
    per-run plots (default: the first, i.e. vehicle, topic).
    """
    src = Path(source)
    opts = dict(compare_options or {})
    warnings: list[str] = []
    if not src.exists():
        raise ConfigError(f"{src}: no such log or results location")
    with warnings_module.catch_warnings(record=True) as caught:
        warnings_module.simplefilter("always")
        exp, details = _load_and_compare(src, manifest, opts, max_detail_runs, warnings)
    # what the readers warned about (a truncated log, bytes lost) belongs in the report too
    for w in caught:
        if str(w.message) not in warnings:
            warnings.append(str(w.message))
        warnings_module.warn_explicit(w.message, w.category, w.filename, w.lineno)
    table = exp.table
    th = _resolve_thresholds(thresholds)
    gate: GateResult | None = None
    if th is not None or baseline is not None:
        gate = check(table, th, baseline, expected_runs=[r.name for r in exp.runs])
    report = _compose(
        exp,
        details,
        gate,
        th,
        baseline,
        title=title,
        command=command,
        options=opts,
        warnings=warnings,
        detail_topics=detail_topics,
    )
    html_out = Path(html_path)
    from uwval.reports.html import write_html

    write_html(report, html_out)
    pdf_out: Path | None = None
    if pdf is not None:
        from uwval.reports.pdf import write_pdf

        pdf_out = Path(pdf)
        write_pdf(report, pdf_out)
    plots.close(report.figures())
    return ReportOutcome(html_out, pdf_out, gate, table, len(exp.runs), warnings)


def _load_and_compare(
    src: Path,
    manifest: str | Path | None,
    opts: dict[str, Any],
    max_detail_runs: int,
    warnings: list[str],
) -> tuple[ExperimentResults, list[_RunDetail]]:
    """The results to report and the runs with per-run plots (logs compared here)."""
    if is_log(src):
        from uwval.comparison import compare_logs

        lc = compare_logs(src, **opts)
        run = RunRecord(src.stem if src.is_file() else src.name, src, {}, {}, lc.to_json())
        table = ResultsTable.from_comparisons([(run.name, {}, run.comparison)])
        return ExperimentResults(table, [run], None, [src]), [_RunDetail(run, _pairs_of(lc))]
    exp = load_experiment_results(src, manifest)
    if exp.table.df.empty and any(r.log is not None for r in exp.runs):
        exp = compare_pending(exp, opts)
    details = [_detail_for(run, opts) for run in exp.runs[:max_detail_runs]]
    if len(exp.runs) > max_detail_runs:
        warnings.append(
            f"per-run plots shown for the first {max_detail_runs} of "
            f"{len(exp.runs)} runs (--max-detail-runs)"
        )
    return exp, details


def _detail_for(run: RunRecord, opts: Mapping[str, Any]) -> _RunDetail:
    if run.log is None or not run.log.exists():
        return _RunDetail(run, {}, "log not available: plots need the aligned series")
    from uwval.comparison import compare_logs
    from uwval.errors import UwvalError

    try:
        return _RunDetail(run, _pairs_of(compare_logs(run.log, **opts)))
    except UwvalError as exc:
        return _RunDetail(run, {}, f"cannot compare {run.log}: {exc}")


# ----------------------------------------------------------------------------- composing
def _compose(
    exp: ExperimentResults,
    details: list[_RunDetail],
    gate: GateResult | None,
    th: Thresholds | None,
    baseline: Any,
    *,
    title: str,
    command: str,
    options: Mapping[str, Any],
    warnings: list[str],
    detail_topics: Sequence[str] | None,
) -> Report:
    table = exp.table
    now = datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M:%S UTC")
    verdict = "not checked" if gate is None else ("PASS" if gate.passed else "FAIL")
    sub = (
        f"{len(exp.runs)} run(s), topics: {', '.join(table.topics) or 'none'}; "
        f"factors: {', '.join(table.factors) or 'none'}"
    )
    report = Report(title=title, subtitle=sub, verdict=verdict, generated=now)
    paper = _paper_section(table)
    if paper is not None:  # the paper's table opens the report (page 1 of the PDF)
        report.sections.append(paper)
    report.sections.append(_verdict_section(gate, th, baseline, exp, warnings))
    report.sections.append(_summary_section(table))
    report.sections += _factor_sections(table)
    report.sections.append(_runs_section(table))
    report.sections += _detail_sections(details, detail_topics)
    bridge = _bridge_section(exp)
    if bridge is not None:
        report.sections.append(bridge)
    report.sections.append(_provenance_section(exp, th, baseline, options, command))
    return report


def _verdict_section(
    gate: GateResult | None,
    th: Thresholds | None,
    baseline: Any,
    exp: ExperimentResults,
    warnings: list[str],
) -> Section:
    sec = Section("verdict", "Verdict")
    if gate is None:
        sec.blocks.append(
            Text("No thresholds or baseline given: the results are not gated.", css="neutral")
        )
    else:
        head = gate.format(limit=0).splitlines()[0]
        sec.blocks.append(Text(head, css="pass" if gate.passed else "fail"))
        against = []
        if th is not None:
            against.append(f"thresholds {th.source} ({len(th.rules)} rules)")
        if baseline is not None:
            against.append(f"baseline {baseline if not isinstance(baseline, ResultsTable) else ''}")
        sec.blocks.append(Text("Checked against " + " and ".join(against) + "."))
        if gate.violations:
            t = Table(
                "What regressed",
                [
                    "kind",
                    "metric",
                    "run",
                    "topic",
                    "axis",
                    "factor levels",
                    "value",
                    "bound",
                    "rule",
                ],
                [],
            )
            for v in gate.violations[:200]:
                levels = ", ".join(f"{k}={fmt_num(x)}" for k, x in v.factors.items())
                unit = f" {v.unit}" if v.unit else ""
                t.rows.append(
                    [
                        v.kind.value,
                        v.metric,
                        v.run,
                        v.topic,
                        v.axis,
                        levels,
                        fmt_num(v.value) + unit,
                        f"{v.op} {fmt_num(v.bound)}{unit}",
                        v.rule + (f" ({v.note})" if v.note else ""),
                    ]
                )
                t.flags[(len(t.rows) - 1, 6)] = "bad"
            if len(gate.violations) > 200:
                t.caption = f"first 200 of {len(gate.violations)} violations"
            sec.blocks.append(t)
        if gate.skipped:
            sec.blocks.append(
                Text(
                    [*gate.skipped[:10]]
                    + ([f"... {len(gate.skipped) - 10} more"] if len(gate.skipped) > 10 else []),
                    kind="list",
                )
            )
    problems = [f"{f.get('name', '?')}: {f.get('error', '')}" for f in exp.failed]
    if problems:
        sec.blocks.append(Text("Failed runs: ", css="fail"))
        sec.blocks.append(Text(problems, kind="list"))
    if warnings:
        sec.blocks.append(Text(warnings, kind="list"))
    run_warnings = exp.run_warnings()
    if run_warnings:
        sec.blocks.append(Text("Warnings of the compared logs: ", css="fail"))
        sec.blocks.append(
            Text(
                [f"{run}: {w}" for run, ws in run_warnings.items() for w in ws],
                kind="list",
            )
        )
    return sec


def _summary_section(table: ResultsTable) -> Section:
    """The paper's three metrics across all runs, per topic and axis."""
    sec = Section("summary", "Summary: absolute error, MAE and Pearson r")
    levels = factor_levels(table)
    if levels:
        sec.blocks.append(
            Text(
                [
                    f"{factor_label(f)}: " + ", ".join(fmt_num(v) for v in lv)
                    for f, lv in levels.items()
                ],
                kind="list",
            )
        )
    t = Table(
        "All runs",
        [
            "topic",
            "axis",
            "unit",
            "MAE mean",
            "MAE worst",
            "max |error| worst",
            "p95 |error| worst",
            "Pearson r mean",
            "Pearson r lowest",
            "r undefined",
        ],
        [],
        caption="Absolute error = |Unity - Gazebo| per sample; MAE its mean per run; "
        "worst = over runs. Pearson r of the Unity and Gazebo series (undefined "
        "when a series is constant).",
    )
    df = table.df
    for topic in table.topics:
        for a in AXES:
            rows = df[(df["topic"] == topic) & (df["axis"] == a)]
            if rows.empty:
                continue

            def vals(metric: str, rows: pd.DataFrame = rows) -> np.ndarray:
                return rows.loc[rows["metric"] == metric, "value"].to_numpy(dtype=float)

            mae, mx, p95, r = vals("mae"), vals("max"), vals("p95"), vals("pearson_r")
            t.rows.append(
                [
                    topic,
                    a,
                    AXIS_UNITS[a],
                    fmt_num(_nanmean(mae)),
                    fmt_num(_nanmax(mae)),
                    fmt_num(_nanmax(mx)),
                    fmt_num(_nanmax(p95)),
                    fmt_num(_nanmean(r), 6),
                    fmt_num(_nanmin(r), 6),
                    str(int(np.isnan(r).sum())),
                ]
            )
    sec.blocks.append(t)
    norm = df[(df["axis"] == "position_norm") & df["metric"].isin(["mean", "max", "rmse"])]
    if not norm.empty:
        piv = norm.pivot_table(
            index="topic", columns="metric", values="value", aggfunc="max", sort=False
        )
        nt = Table("3-D position error norm (worst run)", ["topic", *list(piv.columns)], [])
        for topic_key, row in piv.iterrows():
            nt.rows.append([str(topic_key), *[fmt_num(v) + " m" for v in row.to_numpy()]])
        sec.blocks.append(nt)
    return sec


def _nanmean(a: np.ndarray) -> float:
    return float(np.nanmean(a)) if np.isfinite(a).any() else float("nan")


def _nanmax(a: np.ndarray) -> float:
    return float(np.nanmax(a)) if np.isfinite(a).any() else float("nan")


def _nanmin(a: np.ndarray) -> float:
    return float(np.nanmin(a)) if np.isfinite(a).any() else float("nan")


def _roundoff_line(skip: Mapping[str, Sequence[str]]) -> str:
    """One line naming the axes left out of the statistics, or ''."""
    if not skip:
        return ""
    named = "; ".join(f"{topic} {', '.join(axes)}" for topic, axes in skip.items())
    return (
        f"Not analysed (no ANOVA, no box plot): {named}: their values are round-off "
        f"(the axis does not move in any run, or its max |error| < {ROUNDOFF_FLOOR:g} m or deg)."
    )


def _triple(values: Sequence[float]) -> str:
    return " / ".join(fmt_num(v) for v in values)


def _paper_section(table: ResultsTable) -> Section | None:
    """The paper's table: per factor level, absolute error (worst max), MAE (mean over the
    runs at that level) and Pearson r (lowest), for the vehicle (the first topic)."""
    vary = table.varying_factors()
    if not vary or not table.topics:
        return None
    topic = table.topics[0]
    skip = set(roundoff_axes(table).get(topic, ()))
    df = table.df[(table.df["topic"] == topic) & table.df["axis"].isin(AXES)]
    sec = Section("paper", f"Per factor level: absolute error, MAE, Pearson r ({topic})")
    t = Table(
        "The paper's validation metrics per factor level",
        [
            "factor = level",
            "runs",
            "max |e| x / y / z (m)",
            "MAE x / y / z (m)",
            "max |e| roll / pitch / yaw (deg)",
            "MAE roll / pitch / yaw (deg)",
            "Pearson r lowest",
        ],
        [],
        caption="Absolute error |Unity - Gazebo| per sample: its worst max over the runs at "
        "that level; MAE: mean over those runs; Pearson r: lowest over the runs and the axes "
        "that move (round-off axes left out).",
    )
    for f in vary:
        for level in factor_levels(table)[f]:
            rows = df[df[f] == level]

            def agg(
                metric: str, how: str, axes: Sequence[str], rows: pd.DataFrame = rows
            ) -> list[float]:
                out = []
                for a in axes:
                    sel = (rows["axis"] == a) & (rows["metric"] == metric)
                    v = rows.loc[sel, "value"].to_numpy(dtype=float)
                    out.append(_nanmax(v) if how == "max" else _nanmean(v))
                return out

            pos, rot = ("x", "y", "z"), ("roll", "pitch", "yaw")
            r = rows.loc[
                (rows["metric"] == "pearson_r") & ~rows["axis"].isin(list(skip)), "value"
            ].to_numpy(dtype=float)
            t.rows.append(
                [
                    f"{factor_label(f)} = {fmt_num(level)}",
                    str(rows["run"].nunique()),
                    _triple(agg("max", "max", pos)),
                    _triple(agg("mae", "mean", pos)),
                    _triple(agg("max", "max", rot)),
                    _triple(agg("mae", "mean", rot)),
                    fmt_num(_nanmin(r), 6),
                ]
            )
    sec.blocks.append(t)
    return sec


def _factor_sections(table: ResultsTable) -> list[Section]:
    vary = table.varying_factors()
    if not vary:
        return []
    out = []
    skip = roundoff_axes(table)
    skip_line = _roundoff_line(skip)
    for f in vary:
        sec = Section(f"factor-{f}", f"Factor: {factor_label(f)}")
        summ = summarize_by_level(table, f)
        if not summ.empty:
            piv = summ.pivot_table(
                index=[f, "topic", "axis"],
                columns="metric",
                values=["mean", "max", "min"],
                sort=False,
            )
            t = Table(
                f"Per level of {f}",
                [
                    factor_label(f),
                    "topic",
                    "axis",
                    "MAE mean",
                    "max |error| worst",
                    "Pearson r mean",
                    "Pearson r lowest",
                    "runs",
                ],
                [],
            )
            counts = summ[summ["metric"] == "mae"].set_index([f, "topic", "axis"])["n"]
            for key, row in piv.iterrows():
                level, topic, axis = cast(tuple[Any, Any, Any], key)
                t.rows.append(
                    [
                        fmt_num(level),
                        str(topic),
                        str(axis),
                        fmt_num(row.get(("mean", "mae"))),
                        fmt_num(row.get(("max", "max"))),
                        fmt_num(row.get(("mean", "pearson_r")), 6),
                        fmt_num(row.get(("min", "pearson_r")), 6),
                        str(int(counts.get((level, topic, axis), 0))),
                    ]
                )
            sec.blocks.append(t)
        if skip_line:  # said once per factor, before its statistics
            sec.blocks.append(Text(skip_line, css="neutral"))
        an = anova_oneway(table, f)
        if skip and not an.empty:  # no statistics on round-off
            keep = [a not in skip.get(t, ()) for t, a in zip(an["topic"], an["axis"], strict=True)]
            an = an[keep]
        at = Table(
            f"One-way ANOVA of MAE across levels of {f}",
            ["topic", "axis", "F", "p", "df between", "df within", "note"],
            [],
            caption="scipy.stats.f_oneway; p < 0.05 flags a level effect on the error.",
        )
        for _, row in an.iterrows():
            at.rows.append(
                [
                    row["topic"],
                    row["axis"],
                    fmt_num(row["f_stat"]),
                    fmt_num(row["p_value"]),
                    str(row["df_between"]),
                    str(row["df_within"]),
                    row["note"],
                ]
            )
            if isinstance(row["p_value"], float) and row["p_value"] < 0.05:
                at.flags[(len(at.rows) - 1, 3)] = "warn"
        sec.blocks.append(at)
        for topic in table.topics:
            sec.blocks.append(
                Plot(
                    f"MAE per level of {f}: {topic}",
                    plots.box_mae_figure(
                        table, f, topic, axes=[a for a in AXES if a not in skip.get(topic, ())]
                    ),
                    "Each box holds the runs at one level; whiskers 1.5 IQR.",
                )
            )
        out.append(sec)
    me = Section("main-effects", "Main effects")
    for topic in table.topics:
        me.blocks.append(
            Plot(
                f"Main effects on MAE: {topic}",
                plots.main_effects_figure(table, topic),
                "Mean MAE over all runs at each factor level.",
            )
        )
    out.append(me)
    pairs = two_way_pairs(table)
    if pairs:
        tw = Section("two-way", "Two-way tables (mean MAE)")
        for a, b in pairs:
            for topic in table.topics:
                for axis in ("x", "yaw"):
                    piv = two_way_table(table, a, b, topic=topic, axis=axis)
                    if piv.empty:
                        continue
                    t = Table(
                        f"{topic} {axis} ({AXIS_UNITS[axis]}): {a} (rows) x {b} (columns)",
                        [
                            f"{factor_label(a)} \\ {factor_label(b)}",
                            *[fmt_num(c) for c in piv.columns],
                        ],
                        [],
                    )
                    for level, row in piv.iterrows():
                        t.rows.append([fmt_num(level), *[fmt_num(v) for v in row.to_numpy()]])
                    tw.blocks.append(t)
        out.append(tw)
    return out


def _runs_section(table: ResultsTable) -> Section:
    sec = Section("runs", "Runs")
    rf = table.run_factors()
    for topic in table.topics:
        cols = [
            "run",
            *[factor_label(f) for f in table.factors],
            *[f"MAE {a} ({AXIS_UNITS[a]})" for a in AXES],
            "max |e| (m)",
            *[f"r {a}" for a in AXES],
        ]
        t = Table(f"{topic}", cols, [])
        df = table.df[table.df["topic"] == topic]
        for run in table.runs:
            rows = df[df["run"] == run]
            if rows.empty:
                continue

            def v(axis: str, metric: str, rows: pd.DataFrame = rows) -> float:
                s = rows.loc[(rows["axis"] == axis) & (rows["metric"] == metric), "value"]
                return float(s.iloc[0]) if len(s) else float("nan")

            t.rows.append(
                [
                    run,
                    *[fmt_num(rf.loc[run, f]) for f in table.factors],
                    *[fmt_num(v(a, "mae")) for a in AXES],
                    fmt_num(v("position_norm", "max")),
                    *[fmt_num(v(a, "pearson_r"), 6) for a in AXES],
                ]
            )
        sec.blocks.append(t)
    return sec


def _detail_sections(details: list[_RunDetail], topics: Sequence[str] | None) -> list[Section]:
    out: list[Section] = []
    for d in details:
        run = d.run
        levels = ", ".join(f"{k}={fmt_num(v)}" for k, v in run.factors.items())
        sec = Section(
            f"run-{run.name}",
            f"Run {run.name}" + (f" ({levels})" if levels else ""),
            level=2,
            collapsed=len(out) >= 2,
        )
        if d.error:
            sec.blocks.append(Text(d.error, css="neutral"))
        comp = run.comparison or {}
        from uwval.results import topic_results

        per_topic = dict(topic_results(comp)) if comp else {}
        for topic, res in per_topic.items():
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
                ci = m.get("pearson_ci")
                t.rows.append(
                    [
                        a,
                        AXIS_UNITS[a],
                        *[fmt_num(m.get(k)) for k in ("mae", "rmse", "max", "p95", "bias", "std")],
                        fmt_r(m.get("pearson_r")),
                        fmt_interval(*ci) if ci else "n/a",
                        str(m.get("pearson_reason") or ""),
                    ]
                )
            n = res.get("n_samples")
            t.caption = f"{n} aligned samples" if n is not None else ""
            sec.blocks.append(t)
        want = list(topics) if topics else list(d.pairs)[:1]
        for topic in want:
            pair = d.pairs.get(topic)
            if pair is None or len(pair.t) == 0:
                continue
            res = per_topic.get(topic, {})
            rs = {a: (res.get("axes", {}).get(a, {}) or {}).get("pearson_r") for a in AXES}
            name = f"{run.name} / {topic}"
            sec.blocks.append(
                Plot(
                    f"Trajectory overlay: {name}",
                    plots.trajectory_figure(pair, name),
                    "ENU world: x east, y north, z up (m).",
                )
            )
            sec.blocks.append(
                Plot(
                    f"Per-axis series and error: {name}",
                    plots.timeseries_figure(pair, name),
                    "Left: both simulators; right: Unity - Gazebo (signed) and its absolute value.",
                )
            )
            sec.blocks.extend(_error_plots(pair, name))  # viz: histogram, coloured path
            sec.blocks.append(
                Plot(
                    f"Unity vs Gazebo: {name}",
                    plots.scatter_figure(pair, rs, name),
                    "Points on y = x mean perfect correspondence; r from the compare engine.",
                )
            )
        out.append(sec)
    return out


def _error_plots(pair: Any, name: str) -> list[Plot]:
    """The per-run error histograms and the trajectory coloured by the position error."""
    return [
        Plot(
            f"Error histograms: {name}",
            plots.error_histogram_figure(pair, name),
            "Signed Unity - Gazebo per axis (m, deg), position-error norm (m) and rotation "
            "angle (deg); solid line: mean, dashed: RMSE.",
        ),
        Plot(
            f"Trajectory coloured by the position error: {name}",
            plots.trajectory_error_figure(pair, name),
            "Gazebo path from above (ENU x-y, m) coloured by |p_Unity - p_Gazebo| (m); "
            "Unity dashed grey (as evo_ape --plot_mode xy).",
        ),
    ]


def _bridge_section(exp: ExperimentResults) -> Section | None:
    stats = {r.name: r.bridge for r in exp.runs if r.bridge}
    if not stats:
        return None
    sec = Section("bridge", "Bridge statistics")
    keys: list[str] = []
    for s in stats.values():
        keys += [k for k in s if k not in keys]
    t = Table(
        "Per run",
        ["run", *keys],
        [],
        caption="As counted by the TCP bridge and the Unity-side client (latency, drops, "
        "queue); units as in the key names.",
    )
    for name, s in stats.items():
        t.rows.append(
            [
                name,
                *[
                    fmt_num(s.get(k)) if not isinstance(s.get(k), (dict, list)) else str(s.get(k))
                    for k in keys
                ],
            ]
        )
    sec.blocks.append(t)
    fig = plots.bridge_figure(stats)
    if fig is not None:
        sec.blocks.append(
            Plot(
                "Bridge statistics per run",
                fig,
                "Bars in the order of the table above, labelled by the part "
                "of the run name that tells runs apart (else the row number, "
                "from 0).",
            )
        )
    return sec


def _provenance_section(
    exp: ExperimentResults,
    th: Thresholds | None,
    baseline: Any,
    options: Mapping[str, Any],
    command: str,
) -> Section:
    import uwval

    sec = Section("provenance", "Provenance", collapsed=False)
    info = [
        ["uwval version", uwval.__version__],
        ["python", sys.version.split()[0]],
        ["platform", platform.platform()],
        ["generated", datetime.now(timezone.utc).isoformat(timespec="seconds")],
    ]
    if command:
        info.append(["command", command])
    info.append(
        ["compare options", ", ".join(f"{k}={v}" for k, v in options.items()) or "defaults"]
    )
    info.append(["thresholds", th.source if th is not None else "none"])
    if baseline is not None:
        info.append(
            [
                "baseline",
                str(baseline) if not isinstance(baseline, ResultsTable) else "in-memory table",
            ]
        )
    if exp.manifest:
        e = exp.manifest.get("experiment") or {}
        info.append(
            [
                "experiment",
                ", ".join(f"{k}={v}" for k, v in e.items() if not isinstance(v, (dict, list))),
            ]
        )
    sec.blocks.append(Table("Tool and options", ["item", "value"], info))
    inputs: list[Path] = list(exp.sources)
    for r in exp.runs:
        if r.log is not None and r.log.exists() and r.log not in inputs:
            inputs.append(r.log)
    if baseline is not None and not isinstance(baseline, ResultsTable):
        inputs.append(Path(baseline))
    if th is not None and Path(th.source).is_file():
        inputs.append(Path(th.source))
    t = Table("Inputs", ["file", "bytes", "sha256"], [])
    for p in inputs:
        if not p.exists():
            continue
        size = (
            p.stat().st_size
            if p.is_file()
            else sum(f.stat().st_size for f in p.rglob("*") if f.is_file())
        )
        t.rows.append([str(p), str(size), sha256_of(p)])
    sec.blocks.append(t)
    return sec
