"""The report's tables of results (the paper's table, the summary, per level, one-way ANOVA,
two-way, the runs, the bridge, provenance), each in the report's one number format
(:mod:`uwval.reports.numbers`): positions in mm, angles in deg, r with 4 decimals."""

from __future__ import annotations

import contextlib
import math
import platform
import sys
from collections.abc import Mapping, Sequence
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, cast

import numpy as np
import pandas as pd

from uwval.gate import Thresholds, display_path
from uwval.reports.content import Section, Table, Text
from uwval.reports.numbers import Quantity, fmt, fmt_level, fmt_p, quantity_of, unit_suffix
from uwval.results import (
    AXES,
    AXIS_UNITS,
    ROUNDOFF_FLOOR,
    ExperimentResults,
    ResultsTable,
    anova_oneway,
    factor_label,
    factor_levels,
    roundoff_axes,
    summarize_by_level,
    two_way_pairs,
    two_way_table,
)

POSITION, ROTATION = ("x", "y", "z"), ("roll", "pitch", "yaw")


def axis_quantity(axis: str) -> Quantity:
    """Lengths (x y z, the position norm) in mm, angles in deg."""
    return quantity_of("", AXIS_UNITS.get(axis, ""))


def shown_unit(axis: str) -> str:
    return unit_suffix(axis_quantity(axis)).strip(" ()")


def level_label(factor: str, level: Any) -> str:
    """``force = 5 N``: a factor level with the factor's unit."""
    unit = factor_label(factor).removeprefix(factor).strip(" ()")
    return f"{factor} = {fmt_level(level)}" + (f" {unit}" if unit else "")


def pose_wide(table: ResultsTable) -> pd.DataFrame:
    """Pose metrics one row per (run, topic), columns (axis, metric): one pivot instead of a
    filter per cell (the runs table of 54 runs has ~1,800 cells)."""
    df = table.df[table.df["axis"].isin([*AXES, "position_norm"])]
    return df.pivot_table(
        index=["run", "topic"], columns=["axis", "metric"], values="value", aggfunc="first"
    )


def _stat(values: np.ndarray, how: str) -> float:
    v = values[np.isfinite(values)]
    if len(v) == 0:
        return math.nan
    if how == "mean":
        return float(np.mean(v))
    return float(np.max(v) if how == "max" else np.min(v))


def _values(rows: pd.DataFrame, axis: str, metric: str) -> np.ndarray:
    sel = (rows["axis"] == axis) & (rows["metric"] == metric)
    return rows.loc[sel, "value"].to_numpy(dtype=float)


def _triple(values: Sequence[float], q: Quantity) -> str:
    return " / ".join(fmt(v, q) for v in values)


def paper_section(table: ResultsTable) -> Section | None:
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
            "max |e| x / y / z (mm)",
            "MAE x / y / z (mm)",
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
            r = rows.loc[
                (rows["metric"] == "pearson_r") & ~rows["axis"].isin(list(skip)), "value"
            ].to_numpy(dtype=float)
            t.rows.append(
                [
                    level_label(f, level),
                    str(rows["run"].nunique()),
                    _triple(
                        [_stat(_values(rows, a, "max"), "max") for a in POSITION], Quantity.LENGTH
                    ),
                    _triple(
                        [_stat(_values(rows, a, "mae"), "mean") for a in POSITION], Quantity.LENGTH
                    ),
                    _triple(
                        [_stat(_values(rows, a, "max"), "max") for a in ROTATION], Quantity.ANGLE
                    ),
                    _triple(
                        [_stat(_values(rows, a, "mae"), "mean") for a in ROTATION], Quantity.ANGLE
                    ),
                    fmt(_stat(r, "min"), Quantity.CORRELATION),
                ]
            )
    sec.blocks.append(t)
    return sec


def summary_section(table: ResultsTable) -> Section:
    """The paper's three metrics across all runs, per topic and axis."""
    sec = Section("summary", "Summary: absolute error, MAE and Pearson r")
    levels = factor_levels(table)
    if levels:
        sec.blocks.append(
            Text(
                [
                    f"{factor_label(f)}: " + ", ".join(fmt_level(v) for v in lv)
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
            "max |e| worst",
            "p95 |e| worst",
            "r mean",
            "r lowest",
            "r undefined",
        ],
        [],
        caption="Absolute error = |Unity - Gazebo| per sample; MAE its mean per run; worst = "
        "over runs. Pearson r of the Unity and Gazebo series (undefined when a series is "
        "constant).",
    )
    df = table.df
    for topic in table.topics:
        for a in AXES:
            rows = df[(df["topic"] == topic) & (df["axis"] == a)]
            if rows.empty:
                continue
            q = axis_quantity(a)
            mae, mx, p95 = (_values(rows, a, m) for m in ("mae", "max", "p95"))
            r = _values(rows, a, "pearson_r")
            t.rows.append(
                [
                    topic,
                    a,
                    shown_unit(a),
                    fmt(_stat(mae, "mean"), q),
                    fmt(_stat(mae, "max"), q),
                    fmt(_stat(mx, "max"), q),
                    fmt(_stat(p95, "max"), q),
                    fmt(_stat(r, "mean"), Quantity.CORRELATION),
                    fmt(_stat(r, "min"), Quantity.CORRELATION),
                    str(int(np.isnan(r).sum())),
                ]
            )
    sec.blocks.append(t)
    norm = df[(df["axis"] == "position_norm") & df["metric"].isin(["mean", "max", "rmse"])]
    if not norm.empty:
        piv = norm.pivot_table(
            index="topic", columns="metric", values="value", aggfunc="max", sort=False
        )
        nt = Table("3-D position error norm, worst run (mm)", ["topic", *list(piv.columns)], [])
        for topic_key, row in piv.iterrows():
            nt.rows.append([str(topic_key), *[fmt(v, Quantity.LENGTH) for v in row.to_numpy()]])
        sec.blocks.append(nt)
    return sec


def roundoff_line(skip: Mapping[str, Sequence[str]]) -> str:
    """One line naming the axes left out of the statistics, or ''."""
    if not skip:
        return ""
    named = "; ".join(f"{topic} {', '.join(axes)}" for topic, axes in skip.items())
    return (
        f"Not analysed (no ANOVA, no level plot): {named}: their values are round-off "
        f"(the axis does not move in any run, or its max |error| < {ROUNDOFF_FLOOR:g} m or deg)."
    )


def _per_level_table(table: ResultsTable, f: str) -> Table | None:
    summ = summarize_by_level(table, f)
    if summ.empty:
        return None
    piv = summ.pivot_table(
        index=[f, "topic", "axis"], columns="metric", values=["mean", "max", "min"], sort=False
    )
    t = Table(
        f"Per level of {f}",
        [
            factor_label(f),
            "topic",
            "axis",
            "unit",
            "MAE mean",
            "max |e| worst",
            "r mean",
            "r lowest",
            "runs",
        ],
        [],
    )
    counts = summ[summ["metric"] == "mae"].set_index([f, "topic", "axis"])["n"]
    for key, row in piv.iterrows():
        level, topic, axis = cast(tuple[Any, Any, Any], key)
        q = axis_quantity(str(axis))
        t.rows.append(
            [
                fmt_level(level),
                str(topic),
                str(axis),
                shown_unit(str(axis)),
                fmt(row.get(("mean", "mae")), q),
                fmt(row.get(("max", "max")), q),
                fmt(row.get(("mean", "pearson_r")), Quantity.CORRELATION),
                fmt(row.get(("min", "pearson_r")), Quantity.CORRELATION),
                str(int(counts.get((level, topic, axis), 0))),
            ]
        )
    return t


def _anova_table(table: ResultsTable, f: str, skip: Mapping[str, Sequence[str]]) -> Table:
    an = anova_oneway(table, f)
    if skip and not an.empty:  # no statistics on round-off
        keep = [a not in skip.get(t, ()) for t, a in zip(an["topic"], an["axis"], strict=True)]
        an = an[keep]
    at = Table(
        f"One-way ANOVA of MAE across levels of {f}",
        ["topic", "axis", "F", "p", "df between", "df within", "note"],
        [],
        caption="scipy.stats.f_oneway, one factor at a time: on a full factorial the other "
        "factors' variance sits in the residual, so read the factorial model of the answer "
        "section first.",
    )
    for _, row in an.iterrows():
        p = row["p_value"]
        at.rows.append(
            [
                row["topic"],
                row["axis"],
                fmt(row["f_stat"], Quantity.PLAIN),
                fmt_p(p) if isinstance(p, float) and math.isfinite(p) else "n/a",
                str(row["df_between"]),
                str(row["df_within"]),
                row["note"],
            ]
        )
    return at


def secondary_section(table: ResultsTable) -> Section | None:
    """One factor at a time: per-level tables and one-way ANOVAs (collapsed: the factorial
    analysis is the primary view)."""
    vary = table.varying_factors()
    if not vary:
        return None
    sec = Section("one-way", "Secondary view: one factor at a time", collapsed=True)
    skip = roundoff_axes(table)
    line = roundoff_line(skip)
    if line:
        sec.blocks.append(Text(line, css="neutral"))
    for f in vary:
        t = _per_level_table(table, f)
        if t is not None:
            sec.blocks.append(t)
        sec.blocks.append(_anova_table(table, f, skip))
    return sec


def two_way_section(table: ResultsTable) -> Section | None:
    pairs = two_way_pairs(table)
    if not pairs:
        return None
    tw = Section("two-way", "Two-way tables (mean MAE)", collapsed=True)
    for a, b in pairs:
        for topic in table.topics[:1]:
            for axis in ("x", "yaw"):
                piv = two_way_table(table, a, b, topic=topic, axis=axis)
                if piv.empty:
                    continue
                q = axis_quantity(axis)
                t = Table(
                    f"{topic} {axis} ({shown_unit(axis)}): {a} (rows) x {b} (columns)",
                    [
                        f"{factor_label(a)} \\ {factor_label(b)}",
                        *[fmt_level(c) for c in piv.columns],
                    ],
                    [],
                )
                for level, row in piv.iterrows():
                    t.rows.append([fmt_level(level), *[fmt(v, q) for v in row.to_numpy()]])
                tw.blocks.append(t)
    return tw


def run_ids(table: ResultsTable) -> dict[str, str]:
    """Each run's label in the runs table: the part of its name that tells the runs apart
    (``default-16-force=5_...`` -> ``16``), else the name (short names) or the row number."""
    from uwval.reports.plots import short_run_labels

    runs = table.runs
    return dict(zip(runs, short_run_labels(runs, max_len=24), strict=True))


def runs_section(table: ResultsTable, failing: Mapping[str, int]) -> Section:
    """Every run: factor levels, MAE per axis, worst position error, the lowest Pearson r
    (and its axis) and the gate's verdict. One r column, not six: the table then fits a
    1400 px window and the A4 width whole."""
    sec = Section("runs", "Runs", collapsed=len(table.runs) > 20)
    wide = pose_wide(table)
    rf = table.run_factors()
    ids = run_ids(table)
    if any(ids[r] != r for r in table.runs):
        sec.blocks.append(
            Text(
                f"Runs labelled by the part of their name that tells them apart: "
                f"{table.runs[0]} is {ids[table.runs[0]]}.",
                css="neutral",
            )
        )
    for topic in table.topics:
        cols = [
            "run",
            *[factor_label(f) for f in table.factors],
            *[f"MAE {a} ({shown_unit(a)})" for a in AXES],
            "max |e| (mm)",
            "r lowest (axis)",
            "gate",
        ]
        t = Table(topic, cols, [])
        for run in table.runs:
            if (run, topic) not in wide.index:
                continue
            w: Any = wide.loc[(run, topic)]

            def v(axis: str, metric: str, w: Any = w) -> float:
                return float(w.get((axis, metric), math.nan))

            n_bad = failing.get(run, 0)
            rs = {a: v(a, "pearson_r") for a in AXES if math.isfinite(v(a, "pearson_r"))}
            low = min(rs, key=lambda a: rs[a]) if rs else ""
            r_text = f"{fmt(rs[low], Quantity.CORRELATION)} ({low})" if low else "n/a"
            t.rows.append(
                [
                    ids[run],
                    *[fmt_level(rf.loc[run, f]) for f in table.factors],
                    *[fmt(v(a, "mae"), axis_quantity(a)) for a in AXES],
                    fmt(v("position_norm", "max"), Quantity.LENGTH),
                    r_text,
                    f"FAIL ({n_bad})" if n_bad else "PASS",
                ]
            )
            t.flags[(len(t.rows) - 1, len(cols) - 1)] = "bad" if n_bad else "good"
        sec.blocks.append(t)
    return sec


def _bridge_quantity(key: str) -> Quantity:
    if key.endswith("_s"):
        return Quantity.DURATION
    if key.endswith("_ms"):
        return Quantity.MILLISECONDS
    return Quantity.COUNT if not key.endswith(("_hz", "_ratio")) else Quantity.PLAIN


def bridge_section(exp: ExperimentResults) -> Section | None:
    """The bridge's counters over the runs: one row per statistic (min, median, max and
    the run at the max), so that 20 counters of 54 runs fit one narrow table."""
    stats = {r.name: r.bridge for r in exp.runs if r.bridge}
    if not stats:
        return None
    frame = pd.DataFrame.from_dict(stats, orient="index")
    numeric = [
        c
        for c in frame.columns
        if pd.api.types.is_numeric_dtype(frame[c]) and not pd.api.types.is_bool_dtype(frame[c])
    ]
    sec = Section("bridge", "Bridge statistics", collapsed=True)
    t = Table(
        f"Over {len(stats)} run(s)",
        ["statistic", "unit", "min", "median", "max", "run at max"],
        [],
        caption="As counted by the TCP bridge and the Unity-side client (latency, drops, "
        "queue); times in ms.",
    )
    for key in numeric:
        col = frame[key].astype(float)
        q = _bridge_quantity(str(key))
        shown = str(key).removesuffix("_s").removesuffix("_ms")
        at = str(col.idxmax()) if col.notna().any() else "n/a"
        t.rows.append(
            [
                shown,
                unit_suffix(q).strip(" ()"),
                fmt(col.min(), q),
                fmt(col.median(), q),
                fmt(col.max(), q),
                at,
            ]
        )
    texts = [c for c in frame.columns if c not in numeric]
    for key in texts:
        vals = {str(v) for v in frame[key].dropna() if not isinstance(v, (dict, list))}
        if vals:
            t.rows.append([str(key), "", "", ", ".join(sorted(vals)), "", ""])
    sec.blocks.append(t)
    return sec


def _sha256(path: Path) -> str:
    import hashlib

    h = hashlib.sha256()
    files = [path] if path.is_file() else sorted(p for p in path.rglob("*") if p.is_file())
    for f in files:
        if path.is_dir():
            h.update(str(f.relative_to(path)).encode() + b"\0")
        with open(f, "rb") as fh:
            while chunk := fh.read(1 << 20):
                h.update(chunk)
    return h.hexdigest()


def provenance_section(
    exp: ExperimentResults,
    th: Thresholds | None,
    baseline: str | None,
    options: Mapping[str, Any],
    command: str,
    root: Path | None = None,
) -> Section:
    """Tool, options and inputs (with their SHA-256): what it takes to make the report again.
    Embedded defaults are named as such, never by their install path; files under ``root``
    (the results location) by their path from it (it is named once)."""
    import uwval

    sec = Section("provenance", "Provenance", collapsed=True)
    info = [
        ["uwval version", uwval.__version__],
        ["python", sys.version.split()[0]],
        ["platform", platform.platform()],
        ["generated", datetime.now(timezone.utc).isoformat(timespec="seconds")],
    ]
    if command:
        info.append(["command", command])
    opts = ", ".join(f"{k}={v}" for k, v in options.items()) or "defaults"
    info.append(["compare options", opts])
    info.append(["thresholds", display_path(th.source) if th is not None else "none"])
    if baseline is not None:
        info.append(["baseline", display_path(baseline)])
    if exp.manifest:
        e = exp.manifest.get("experiment") or {}
        info.append(
            [
                "experiment",
                ", ".join(
                    f"{k}={display_path(v) if k == 'path' else v}"
                    for k, v in e.items()
                    if not isinstance(v, (dict, list))
                ),
            ]
        )
    sec.blocks.append(Table("Tool and options", ["item", "value"], info))
    inputs: list[Path] = list(exp.sources)
    for r in exp.runs:
        if r.log is not None and r.log.exists() and r.log not in inputs:
            inputs.append(r.log)
    if baseline is not None:
        inputs.append(Path(baseline))
    if th is not None and Path(th.source).is_file():
        inputs.append(Path(th.source))
    base = None if root is None else (root if root.is_dir() else root.parent).resolve()
    t = Table(
        "Inputs",
        ["file", "bytes", "sha256"],
        [],
        caption=f"Relative paths are from {base}." if base is not None else "",
    )
    for p in inputs:
        if not p.exists():
            continue
        size = (
            p.stat().st_size
            if p.is_file()
            else sum(f.stat().st_size for f in p.rglob("*") if f.is_file())
        )
        shown = display_path(p)
        if base is not None and shown == str(p):
            with contextlib.suppress(ValueError):  # outside the results: kept whole
                shown = p.resolve().relative_to(base).as_posix()
        t.rows.append([shown, str(size), _sha256(p)])
    sec.blocks.append(t)
    return sec
