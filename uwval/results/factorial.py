"""The factorial analysis of an experiment, written to ``analysis.json`` (docs/analysis.md).

One-way ANOVAs on a full factorial mislead (the other factors' variation lands in the error
term): per topic, axis and metric this fits every varying factor's main effect and every
two-way interaction by ordinary least squares (statsmodels, Type II sums of squares) and
gives partial eta^2 and p per term, per-level means with 95 % CIs from the replicate noise,
and the lag-normalised error (the metric over the run's mean speed on that axis: the lag
that would make that error, in seconds). Pearson r is marked saturated where it cannot
tell the levels apart. Replicates are runs with the same level of every factor.
"""

from __future__ import annotations

import json
import math
import warnings
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from uwval.errors import ConfigError
from uwval.results.schema import AXES
from uwval.results.table import ResultsTable

SCHEMA = "uwval.analysis/1"
#: Metrics analysed by default: the paper's MAE, the RMSE and Pearson r.
DEFAULT_METRICS: tuple[str, ...] = ("mae", "rmse", "pearson_r")
#: Metrics whose lag-normalised value (metric / mean speed) is given per level.
NORMALISED_METRICS = frozenset({"mae", "rmse"})
#: Pearson r above this in every run cannot tell levels apart, whatever its CI says.
SATURATED_R = 0.999
#: Section of the results table that holds the lag fit (compare JSON ``lag``).
LAG_AXIS = "lag"


def _t975(df: float) -> float:
    from scipy import stats

    return float(stats.t.ppf(0.975, df))


def _clean(obj: Any) -> Any:
    """NaN/inf -> None and numpy scalars -> Python numbers (JSON has no NaN)."""
    if isinstance(obj, dict):
        return {str(k): _clean(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_clean(v) for v in obj]
    if isinstance(obj, np.generic):
        obj = obj.item()
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    return obj


def _per_run(table: ResultsTable, topic: str, axis: str, metric: str) -> pd.Series:
    """One value per run (index: run) of (topic, axis, metric); NaN where undefined."""
    df = table.df
    rows = df[(df["topic"] == topic) & (df["axis"] == axis) & (df["metric"] == metric)]
    return rows.groupby("run", sort=False)["value"].first().astype(float)


def _term_name(term: str, codes: dict[str, str]) -> str:
    """statsmodels' ``C(f0):C(f1)`` -> ``force:torque``."""
    parts = [p.strip() for p in term.split(":")]
    return ":".join(codes.get(p[2:-1] if p.startswith("C(") else p, p) for p in parts)


@dataclass(frozen=True)
class AnovaFit:
    """Terms of a factorial model and its residual (sum of squares, degrees of freedom)."""

    terms: list[dict[str, Any]]
    df_residual: int
    ss_residual: float
    note: str

    @property
    def residual_ms(self) -> float | None:
        """The residual mean square (replicate noise), None when the model cannot test."""
        if self.note or self.df_residual <= 0:
            return None
        return self.ss_residual / self.df_residual


def anova_terms(values: pd.Series, design: pd.DataFrame, factors: Sequence[str]) -> AnovaFit:
    """Main effects and two-way interactions of ``factors`` on ``values`` (one per run,
    index aligned with ``design``'s): OLS, Type II sums of squares.

    Each term: ``term``, ``df``,
    ``sum_sq``, ``f``, ``p``, ``partial_eta_sq`` = SS / (SS + SS_residual) and ``eta_sq`` =
    SS / SS_total (the term's share of the variation across runs: with near-deterministic
    replicates every partial eta^2 nears 1, the share still ranks the terms); F, p and
    partial eta^2 are NaN with a note when the design leaves no residual to test against.
    """
    import statsmodels.formula.api as smf
    from statsmodels.stats.anova import anova_lm

    ok = values.notna()
    y = values[ok].to_numpy(dtype=float)
    if y.size < 2:
        return AnovaFit([], 0, math.nan, "fewer than 2 runs with a value")
    if float(np.ptp(y)) == 0.0:
        return AnovaFit([], 0, math.nan, "every run has the same value")
    codes = {f"f{i}": f for i, f in enumerate(factors)}
    data = pd.DataFrame({"y": y})
    for code, f in codes.items():
        data[code] = design.loc[values.index[ok], f].astype(str).to_numpy()
    mains = [f"C({c})" for c in codes]
    pairs = [f"{a}:{b}" for i, a in enumerate(mains) for b in mains[i + 1 :]]
    formula = "y ~ " + " + ".join(mains + pairs)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # rank-deficient / perfect fits: handled below
        model = smf.ols(formula, data=data).fit()
        try:
            table = anova_lm(model, typ=2)
        except (ValueError, np.linalg.LinAlgError):
            # no residual left (Type II needs its covariance): the sequential sums of
            # squares still say how the variation splits (equal to Type II when balanced)
            table = anova_lm(model, typ=1)
    ss_res = float(table.loc["Residual", "sum_sq"])
    df_res = round(float(table.loc["Residual", "df"]))
    note = ""
    testable = df_res > 0 and ss_res > 1e-12 * float(np.sum((y - y.mean()) ** 2))
    if not testable:
        note = (
            "no residual degrees of freedom (no replicates): F, p and partial eta^2 undefined"
            if df_res <= 0
            else "the model fits every run exactly: F, p and partial eta^2 undefined"
        )
    total = float(np.sum((y - y.mean()) ** 2))
    terms = []
    for name, row in table.drop(index="Residual").iterrows():
        ss = float(row["sum_sq"])
        terms.append(
            {
                "term": _term_name(str(name), codes),
                "df": round(float(row["df"])),
                "sum_sq": ss,
                "f": float(row["F"]) if testable else math.nan,
                "p": float(row["PR(>F)"]) if testable else math.nan,
                "partial_eta_sq": ss / (ss + ss_res) if testable else math.nan,
                "eta_sq": ss / total,
            }
        )
    return AnovaFit(terms, df_res, ss_res, note)


def _mean_ci(x: np.ndarray) -> tuple[float, list[float] | None]:
    """Mean and its 95 % t-interval (None for fewer than 2 values)."""
    m = float(x.mean()) if x.size else math.nan
    if x.size < 2:
        return m, None
    half = _t975(x.size - 1) * float(x.std(ddof=1)) / math.sqrt(x.size)
    return m, [m - half, m + half]


def level_summaries(
    values: pd.Series,
    design: pd.DataFrame,
    factor: str,
    *,
    residual_ms: float | None,
    df_residual: int,
    speed: pd.Series | None,
) -> list[dict[str, Any]]:
    """Per level of ``factor``: n, mean and its 95 % CI (from the model's residual mean
    square, the replicate noise, when the model has one; else a t-interval over the runs of
    the level), and the mean metric / speed with its t-interval when ``speed`` is given."""
    ok = values.notna()
    levels = design.loc[values.index[ok], factor]
    out = []
    for level in sorted(levels.unique().tolist(), key=lambda v: (isinstance(v, str), v)):
        runs = levels.index[levels == level]
        x = values[runs].to_numpy(dtype=float)
        mean, ci = _mean_ci(x)
        if residual_ms is not None and df_residual > 0 and x.size:
            half = _t975(df_residual) * math.sqrt(residual_ms / x.size)
            ci = [mean - half, mean + half]
        item: dict[str, Any] = {"level": level, "n": int(x.size), "mean": mean, "ci95": ci}
        if speed is not None:
            s = speed.reindex(runs).to_numpy(dtype=float)
            good = np.isfinite(s) & (s > 0)
            norm = x[good] / s[good]
            item["normalised"], item["normalised_ci95"] = (
                _mean_ci(norm) if norm.size else (math.nan, None)
            )
        out.append(item)
    return out


def _pearson_saturation(
    table: ResultsTable, topic: str, axis: str, values: pd.Series, levels: dict[str, Any]
) -> tuple[bool, str]:
    """Whether Pearson r cannot tell the levels apart, and why."""
    r = values.dropna().to_numpy(dtype=float)
    if r.size == 0:
        return True, "Pearson r is undefined in every run"
    if bool(np.all(r > SATURATED_R)):
        return True, f"r > {SATURATED_R} in every run: it cannot rank the levels"
    lo = _per_run(table, topic, axis, "pearson_ci_eff_low")
    hi = _per_run(table, topic, axis, "pearson_ci_eff_high")
    widths = (hi - lo).dropna().to_numpy(dtype=float)
    spread = max(
        (
            max(i["mean"] for i in items) - min(i["mean"] for i in items)
            for items in levels.values()
            if items
        ),
        default=0.0,
    )
    if widths.size and spread < float(np.median(widths)):
        return True, (
            f"the level means differ by {spread:.3g}, less than the typical width "
            f"{float(np.median(widths)):.3g} of a run's autocorrelation-aware 95 % CI"
        )
    return False, ""


def analyse_cell(
    table: ResultsTable, topic: str, axis: str, metric: str, factors: Sequence[str]
) -> dict[str, Any]:
    """The analysis of one (topic, axis, metric): model, terms, per-level summaries."""
    design = table.run_factors()
    values = _per_run(table, topic, axis, metric).reindex(design.index)
    fit = (
        anova_terms(values, design, factors)
        if factors
        else AnovaFit([], 0, math.nan, "no factor varies across the runs")
    )
    n = int(values.notna().sum())
    speed = None
    if metric in NORMALISED_METRICS:
        speed = _per_run(table, topic, LAG_AXIS, f"speed.{axis}")
        speed = speed if speed.notna().any() else None
    levels = {
        f: level_summaries(
            values, design, f, residual_ms=fit.residual_ms, df_residual=fit.df_residual, speed=speed
        )
        for f in factors
    }
    mains = list(factors)
    pairs = [f"{a}:{b}" for i, a in enumerate(mains) for b in mains[i + 1 :]]
    cell: dict[str, Any] = {
        "model": "value ~ " + " + ".join(mains + pairs) if factors else "",
        "n": n,
        "df_residual": fit.df_residual,
        "note": fit.note,
        "terms": fit.terms,
        "levels": levels,
    }
    if metric == "pearson_r":
        cell["saturated"], cell["saturated_why"] = _pearson_saturation(
            table, topic, axis, values, levels
        )
    return cell


def _lag_summary(table: ResultsTable, topic: str) -> dict[str, Any] | None:
    """The lag over the runs of one topic (compare JSON ``lag`` rows), or None."""
    fitted = _per_run(table, topic, LAG_AXIS, "fitted_s").dropna()
    if fitted.empty:
        return None
    explained = _per_run(table, topic, LAG_AXIS, "explained").dropna()
    measured = _per_run(table, topic, LAG_AXIS, "measured_s").dropna()
    return {
        "n_runs": int(fitted.size),
        "fitted_s_mean": float(fitted.mean()),
        "fitted_s_min": float(fitted.min()),
        "fitted_s_max": float(fitted.max()),
        "explained_mean": float(explained.mean()) if not explained.empty else math.nan,
        "measured_s_mean": float(measured.mean()) if not measured.empty else None,
    }


def factorial_analysis(
    table: ResultsTable,
    *,
    metrics: Sequence[str] = DEFAULT_METRICS,
    axes: Sequence[str] = AXES,
) -> dict[str, Any]:
    """The whole analysis of an experiment's results table (schema: docs/analysis.md)."""
    factors = table.varying_factors()
    design = table.run_factors()
    cells = design.groupby(factors, dropna=False).size() if factors else pd.Series([len(design)])
    doc: dict[str, Any] = {
        "schema": SCHEMA,
        "n_runs": len(design),
        "factors": {
            f: sorted(design[f].dropna().unique().tolist(), key=lambda v: (isinstance(v, str), v))
            for f in factors
        },
        "replicates": {"min": int(cells.min()), "max": int(cells.max())},
        "lag": {t: _lag_summary(table, t) for t in table.topics},
        "topics": {},
    }
    for topic in table.topics:
        doc["topics"][topic] = {
            axis: {m: analyse_cell(table, topic, axis, m, factors) for m in metrics}
            for axis in axes
        }
    doc["answer"] = answer_sentence(doc)
    cleaned: dict[str, Any] = _clean(doc)
    return cleaned


def _ms(s: float) -> str:
    return f"{s * 1e3:.1f} ms"


def answer_sentence(doc: dict[str, Any], *, axis: str = "x", metric: str = "mae") -> str:
    """The study's answer in a sentence or two: the lag over the runs (first topic) and which
    factors move ``axis`` ``metric``, by partial eta^2."""
    topics = list(doc.get("topics") or {})
    if not topics:
        return "No runs to analyse."
    topic = topics[0]
    parts: list[str] = []
    lag = (doc.get("lag") or {}).get(topic)
    if lag:
        text = (
            f"Unity shows Gazebo's pose {_ms(lag['fitted_s_mean'])} late on average over "
            f"{lag['n_runs']} runs ({_ms(lag['fitted_s_min'])} to {_ms(lag['fitted_s_max'])})"
        )
        if lag.get("explained_mean") is not None:
            text += f", which explains {max(0.0, lag['explained_mean']) * 100:.0f} % of the error"
        if lag.get("measured_s_mean") is not None:
            text += f" (applied stamps: {_ms(lag['measured_s_mean'])})"
        parts.append(text + ".")
    cell = ((doc["topics"][topic].get(axis) or {}).get(metric)) or {}
    ranked = sorted(
        (t for t in cell.get("terms", []) if t.get("eta_sq") is not None),
        key=lambda t: -t["eta_sq"],
    )
    if ranked:
        listed = ", ".join(
            f"{t['term']} {t['eta_sq'] * 100:.0f} %"
            + (
                f" (partial eta^2 {t['partial_eta_sq']:.2f})"
                if t.get("partial_eta_sq") is not None
                else ""
            )
            for t in ranked[:3]
        )
        parts.append(f"Of the variation of {axis} {metric.upper()} across runs: {listed}.")
    elif cell.get("note"):
        parts.append(f"{axis} {metric.upper()}: {cell['note']}.")
    return " ".join(parts) if parts else "No lag and no factor effect could be estimated."


def analysis_path(path: str | Path) -> Path:
    """Where :func:`write_analysis` writes: ``path`` itself when it ends in ``.json`` and is
    not a folder, else ``path / "analysis.json"``."""
    p = Path(path)
    if p.is_dir() or p.suffix.lower() != ".json":
        return p / "analysis.json"
    return p


def write_analysis(table: ResultsTable, path: str | Path) -> Path:
    """Write :func:`factorial_analysis` of ``table`` as JSON; returns the file written."""
    target = analysis_path(path)
    doc = factorial_analysis(table)
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
        target.write_text(json.dumps(doc, indent=1, allow_nan=False) + "\n", encoding="utf-8")
    except OSError as exc:
        raise ConfigError(f"{target}: cannot write the analysis: {exc.strerror or exc}") from None
    return target


def read_analysis(path: str | Path) -> dict[str, Any]:
    """Read an ``analysis.json`` (a file, or the folder holding it)."""
    target = analysis_path(path)
    try:
        doc = json.loads(target.read_text(encoding="utf-8"))
    except OSError as exc:
        raise ConfigError(f"{target}: cannot read the analysis: {exc.strerror or exc}") from None
    except json.JSONDecodeError as exc:
        raise ConfigError(
            f"{target}: line {exc.lineno}: not JSON ({exc.msg}): not an analysis.json"
        ) from None
    if not isinstance(doc, dict) or doc.get("schema") != SCHEMA:
        raise ConfigError(f"{target}: not an analysis.json (schema {SCHEMA!r} expected)")
    return doc
