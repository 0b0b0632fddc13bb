"""Analysis of a results table per factor level: summaries, main effects, one-way ANOVA,
two-way tables. Each function takes a :class:`ResultsTable` and returns a pandas DataFrame
(the report builder plots them).

The factorial analysis (main effects and two-way interactions, partial eta^2, lag-normalised
error, Pearson r's saturation) and ``analysis.json`` live in :mod:`uwval.results.factorial`;
their functions are importable from here too (docs/analysis.md)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import pandas as pd

from uwval.errors import ConfigError
from uwval.results.factorial import (
    answer_sentence,
    factorial_analysis,
    read_analysis,
    write_analysis,
)
from uwval.results.schema import AXES, PAPER_METRICS
from uwval.results.table import ResultsTable

__all__ = [
    "ROUNDOFF_FLOOR",
    "AnovaRow",
    "anova_oneway",
    "answer_sentence",
    "factor_levels",
    "factorial_analysis",
    "main_effects",
    "read_analysis",
    "roundoff_axes",
    "summarize_by_level",
    "two_way_pairs",
    "two_way_table",
    "write_analysis",
]

#: An axis whose worst absolute error over all runs stays below this (m for x y z, deg for
#: roll pitch yaw) carries no signal: float32 storage alone makes ~1e-7..1e-6 of it.
ROUNDOFF_FLOOR = 1e-5


def roundoff_axes(table: ResultsTable, floor: float = ROUNDOFF_FLOOR) -> dict[str, list[str]]:
    """Per topic, the pose axes whose values are round-off, in :data:`AXES` order.

    An axis is round-off when its Pearson r is undefined in every run (a constant series:
    the axis never moves, e.g. the roll of a camera that stays level) or when its max
    absolute error stays below ``floor`` in every run. Statistics over such values (ANOVA,
    box plots) would analyse rounding noise.
    """
    df = table.df
    out: dict[str, list[str]] = {}
    for topic in table.topics:
        sub = df[(df["topic"] == topic) & df["axis"].isin(AXES)]
        found = []
        for axis in AXES:
            rows = sub[sub["axis"] == axis]
            r = rows.loc[rows["metric"] == "pearson_r", "value"].to_numpy(dtype=float)
            mx = rows.loc[rows["metric"] == "max", "value"].to_numpy(dtype=float)
            if not r.size and not mx.size:
                continue
            no_motion = r.size > 0 and bool(np.isnan(r).all())
            tiny = mx.size > 0 and bool(np.all(mx < floor))
            if no_motion or tiny:
                found.append(axis)
        if found:
            out[topic] = found
    return out


def factor_levels(table: ResultsTable) -> dict[str, list[Any]]:
    """Each factor's distinct levels, sorted."""
    rf = table.run_factors()
    return {f: sorted(rf[f].dropna().unique().tolist(), key=_level_key) for f in table.factors}


def _level_key(v: Any) -> tuple[int, Any]:
    return (0, v) if isinstance(v, (int, float)) else (1, str(v))


def summarize_by_level(
    table: ResultsTable,
    factor: str,
    metrics: Sequence[str] = PAPER_METRICS,
    axes: Sequence[str] = AXES,
) -> pd.DataFrame:
    """Per level of ``factor``, per topic, axis and metric: n, mean, std, min, median, max.

    NaN values (undefined metrics) are left out of the statistics and counted in ``n_undefined``.
    """
    _need_factor(table, factor)
    sub = table.select(metric=list(metrics), axis=list(axes))
    if sub.empty:
        return pd.DataFrame()
    g = sub.groupby([factor, "topic", "axis", "metric"], sort=True)["value"]
    out = pd.DataFrame(
        {
            "n": g.count(),
            "n_undefined": g.apply(lambda s: int(s.isna().sum())),
            "mean": g.mean(),
            "std": g.std(ddof=1),
            "min": g.min(),
            "median": g.median(),
            "max": g.max(),
        }
    ).reset_index()
    # levels ascending, then topics in table order (vehicle first), then axes x..yaw
    topic_rank = {t: i for i, t in enumerate(table.topics)}
    axis_rank = {a: i for i, a in enumerate(AXES)}
    key = (
        out[factor].map(lambda v: _level_key(v)),
        out["topic"].map(topic_rank),
        out["axis"].map(axis_rank),
    )
    order = sorted(range(len(out)), key=lambda i: (key[0].iloc[i], key[1].iloc[i], key[2].iloc[i]))
    return out.iloc[order].reset_index(drop=True)


def main_effects(
    table: ResultsTable, metric: str = "mae", axes: Sequence[str] = AXES
) -> pd.DataFrame:
    """Main effects: mean of ``metric`` per level of every factor, per topic and axis.

    Columns: factor, level, topic, axis, mean, n. ``effect`` (per factor/topic/axis) is the
    spread of the level means (max - min), the usual main-effect size for a factorial design.
    """
    frames = []
    sub = table.select(metric=metric, axis=list(axes))
    for f in table.factors:
        if sub.empty or sub[f].nunique(dropna=True) < 1:
            continue
        g = sub.groupby([f, "topic", "axis"], sort=True)["value"].agg(["mean", "count"])
        g = g.reset_index().rename(columns={f: "level", "count": "n"})
        g.insert(0, "factor", f)
        spread = g.groupby(["topic", "axis"])["mean"].transform(lambda s: s.max() - s.min())
        g["effect"] = spread
        frames.append(g)
    if not frames:
        return pd.DataFrame(columns=["factor", "level", "topic", "axis", "mean", "n", "effect"])
    return _order_axes(pd.concat(frames, ignore_index=True))


@dataclass(frozen=True)
class AnovaRow:
    """One one-way ANOVA: does ``factor`` change ``metric`` on (topic, axis)?"""

    factor: str
    topic: str
    axis: str
    metric: str
    f_stat: float
    p_value: float
    df_between: int
    df_within: int
    n_levels: int
    note: str = ""


def anova_oneway(
    table: ResultsTable, factor: str, metric: str = "mae", axes: Sequence[str] = AXES
) -> pd.DataFrame:
    """One-way ANOVA (scipy.stats.f_oneway) of ``metric`` across the levels of ``factor``.

    One row per (topic, axis). F and p are NaN with a ``note`` when the test is undefined:
    fewer than two levels, no replication within levels (df_within = 0), or zero variance.
    """
    from scipy import stats

    _need_factor(table, factor)
    sub = table.select(metric=metric, axis=list(axes)).dropna(subset=["value", factor])
    rows: list[AnovaRow] = []
    for (topic, axis), grp in sub.groupby(["topic", "axis"], sort=False):
        groups = [g["value"].to_numpy() for _, g in grp.groupby(factor, sort=True)]
        k = len(groups)
        n = sum(len(g) for g in groups)
        dfb, dfw = k - 1, n - k
        note = ""
        f_stat = p = math.nan
        if k < 2:
            note = f"{factor} has one level only"
        elif dfw <= 0:
            note = "no replicate runs within levels (df_within = 0)"
        else:
            within = sum(float(((g - g.mean()) ** 2).sum()) for g in groups)
            allv = np.concatenate(groups)
            if within == 0.0 and float(((allv - allv.mean()) ** 2).sum()) == 0.0:
                note = "all values are equal"
            elif within == 0.0:
                note = "no variation within levels (F infinite)"
                f_stat, p = math.inf, 0.0
            else:
                res = stats.f_oneway(*groups)
                f_stat, p = float(res.statistic), float(res.pvalue)
        rows.append(
            AnovaRow(factor, str(topic), str(axis), metric, f_stat, p, dfb, max(dfw, 0), k, note)
        )
    df = pd.DataFrame([r.__dict__ for r in rows], columns=list(AnovaRow.__dataclass_fields__))
    return _order_axes(df)


def two_way_table(
    table: ResultsTable,
    factor_a: str,
    factor_b: str,
    *,
    metric: str = "mae",
    topic: str | None = None,
    axis: str = "x",
) -> pd.DataFrame:
    """Mean ``metric`` per (level of A) x (level of B) for one topic/axis (first topic if None)."""
    _need_factor(table, factor_a)
    _need_factor(table, factor_b)
    topic = topic if topic is not None else (table.topics[0] if table.topics else "")
    sub = table.select(metric=metric, axis=axis, topic=topic)
    if sub.empty:
        return pd.DataFrame()
    return sub.pivot_table(index=factor_a, columns=factor_b, values="value", aggfunc="mean")


def two_way_pairs(table: ResultsTable) -> list[tuple[str, str]]:
    """Pairs of varying factors (for the two-way tables of the report)."""
    vary = table.varying_factors()
    return [(a, b) for i, a in enumerate(vary) for b in vary[i + 1 :]]


def _need_factor(table: ResultsTable, factor: str) -> None:
    if factor not in table.factors:
        raise ConfigError(f"no factor {factor!r} in the results (factors: {table.factors})")


def _order_axes(df: pd.DataFrame) -> pd.DataFrame:
    if "axis" not in df.columns or df.empty:
        return df
    order = {a: i for i, a in enumerate(AXES)}
    key = df["axis"].map(lambda a: order.get(a, len(order)))
    return (
        df.assign(_k=key)
        .sort_values(
            [c for c in ("factor", "_k") if c in df.columns] if "factor" in df.columns else ["_k"],
            kind="stable",
        )
        .drop(columns="_k")
        .reset_index(drop=True)
    )
