"""The gate's checks: threshold rules, the golden baseline, impossible values, reader
warnings and missing runs, each returning a :class:`~uwval.gate.verdict.GateResult`."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import pandas as pd

from uwval.errors import ConfigError
from uwval.gate.rules import (
    ABS_IS_WORSE,
    DEFAULT_BASELINE_METRICS,
    ERROR_AXES,
    HIGHER_IS_WORSE,
    LOWER_IS_WORSE,
    NON_NEGATIVE,
    BaselineTolerance,
    ThresholdRule,
    Thresholds,
    UndefinedPolicy,
)
from uwval.gate.verdict import GateResult, Violation, ViolationKind
from uwval.results import AXES, AXIS_UNITS, MAY_BE_UNDEFINED, MISSING_NOTE, ResultsTable
from uwval.results.schema import SOURCES


def _factor_dict(row: Mapping[Any, Any], factors: Sequence[str]) -> dict[str, Any]:
    out = {}
    for f in factors:
        v = row[f]
        if isinstance(v, float) and math.isnan(v):
            continue
        out[f] = v
    return out


def _level_matches(cell: Any, want: Any) -> bool:
    if isinstance(want, (int, float)) and not isinstance(want, bool):
        try:
            return math.isclose(float(cell), float(want), rel_tol=1e-9, abs_tol=1e-12)
        except (TypeError, ValueError):
            return False
    return str(cell) == str(want)


def _where(row: Mapping[Any, Any]) -> str:
    return f"{row['run']}/{row['topic']}/{row['axis']}"


def _may_skip_undefined(metric: str, note: str) -> bool:
    """True for a value the engine left undefined on purpose, with its reason."""
    return metric in MAY_BE_UNDEFINED and bool(note) and note != MISSING_NOTE


def check_thresholds(table: ResultsTable, thresholds: Thresholds) -> GateResult:
    """Every rule against every matching row of ``table``; every run in a rule's scope must
    have a row for each of the rule's axes."""
    df = table.df
    result = GateResult()
    topics = table.topics
    for rule in thresholds.rules:
        for f in rule.factors:
            if f not in table.factors:
                raise ConfigError(
                    f"{thresholds.source}: rule [{rule.label()}] filters on factor "
                    f"{f!r}, which the results lack (factors: {table.factors})"
                )
        want_topics = [t for t in topics if rule.applies_to(t)]
        in_scope = pd.Series(True, index=df.index)
        for f, level in rule.factors.items():
            in_scope &= df[f].map(lambda c, lv=level: _level_matches(c, lv))
        mask = (
            in_scope
            & (df["metric"] == rule.metric)
            & df["axis"].isin(rule.axes)
            & df["topic"].isin(want_topics)
        )
        rows = df[mask]
        if not want_topics and rule.roles:  # keyed by role: no such topic here is not a failure
            result.skipped.append(
                f"rule [{rule.label()}]: no {' or '.join(rule.roles)} topic in these results"
            )
            continue
        # a topic of the role is there but no value matches (a misspelt metric, a missing
        # axis): a failure, as for a rule keyed by name
        if rows.empty:
            result.violations.append(
                Violation(
                    ViolationKind.NO_MATCH,
                    rule.metric,
                    ",".join(rule.topics),
                    ",".join(rule.axes),
                    "",
                    dict(rule.factors),
                    math.nan,
                    math.nan,
                    "",
                    rule=rule.label(),
                )
            )
            continue
        # a run the rule covers must not escape it: each of its topics (that the rule's
        # patterns name) needs a row for each of the rule's axes
        scope = df.loc[in_scope & df["topic"].isin(want_topics), ["run", "topic"]]
        have = set(zip(rows["run"], rows["topic"], rows["axis"], strict=True))
        for run, topic in dict.fromkeys(zip(scope["run"], scope["topic"], strict=True)):
            lacking = [a for a in rule.axes if (run, topic, a) not in have]
            if lacking:
                result.violations.append(
                    Violation(
                        ViolationKind.NO_MATCH,
                        rule.metric,
                        str(topic),
                        ",".join(lacking),
                        str(run),
                        {},
                        math.nan,
                        math.nan,
                        "",
                        rule=rule.label(),
                        note=f"run {run} has no {rule.metric} for {topic} "
                        f"axis {', '.join(lacking)}",
                    )
                )
        result = result.merge(_rule_rows(rule, rows, table.factors))
    if thresholds.rules and result.checked == 0 and not result.violations:
        # every rule was skipped (no topic of its role): a gate that checked nothing must
        # not pass
        result.violations.append(
            Violation(
                ViolationKind.NO_MATCH,
                "",
                "",
                "",
                "",
                {},
                math.nan,
                math.nan,
                "",
                rule="all",
                note=f"{thresholds.source}: no rule found a value to check in these results "
                "(every rule was skipped)",
            )
        )
    return result


def _rule_rows(rule: ThresholdRule, rows: pd.DataFrame, factors: Sequence[str]) -> GateResult:
    """One rule over its rows: the bounds compared in one numpy pass, a Violation built
    only for a row that breaks them (or is NaN without a reason to skip it)."""
    result = GateResult(checked=len(rows))
    values = rows["value"].to_numpy(dtype=float)
    nan = np.isnan(values)
    bad = nan.copy()
    with np.errstate(invalid="ignore"):
        if rule.max is not None:
            bad |= values > rule.max
        if rule.min is not None:
            bad |= values < rule.min
    for i in np.flatnonzero(bad):  # only the failures (and NaNs) reach Python
        row = rows.iloc[i].to_dict()
        value, note = float(values[i]), str(row["note"])
        common: dict[str, Any] = dict(
            metric=rule.metric,
            topic=str(row["topic"]),
            axis=str(row["axis"]),
            run=str(row["run"]),
            factors=_factor_dict(row, factors),
            unit=str(row["unit"]),
            rule=rule.label(),
        )
        if nan[i]:
            if rule.undefined is UndefinedPolicy.SKIP and _may_skip_undefined(rule.metric, note):
                result.skipped.append(f"{rule.metric} {_where(row)}: {note}")
                continue
            bound = rule.min if rule.min is not None else rule.max
            op = ">=" if rule.min is not None else "<="
            result.violations.append(
                Violation(
                    ViolationKind.UNDEFINED,
                    value=value,
                    bound=float(bound or 0.0),
                    op=op,
                    note=note or MISSING_NOTE,
                    **common,
                )
            )
            continue
        if rule.max is not None and value > rule.max:
            result.violations.append(
                Violation(ViolationKind.THRESHOLD, value=value, bound=rule.max, op="<=", **common)
            )
        if rule.min is not None and value < rule.min:
            result.violations.append(
                Violation(ViolationKind.THRESHOLD, value=value, bound=rule.min, op=">=", **common)
            )
    return result


def _impossible(metric: str, axis: str, value: float) -> str:
    """Why ``value`` cannot be a result of the compare engine ('' when it can)."""
    if math.isnan(value):
        return ""
    if metric in NON_NEGATIVE and axis in ERROR_AXES and value < 0:
        return f"{metric} is a statistic of absolute errors and cannot be negative"
    if metric in ("pearson_r", "pearson_ci_low", "pearson_ci_high") and abs(value) > 1:
        return "a correlation lies in [-1, 1]"
    if metric == "pearson_p" and not 0.0 <= value <= 1.0:
        return "a p-value lies in [0, 1]"
    return ""


def check_values(table: ResultsTable) -> GateResult:
    """Values no comparison can produce (a negative MAE, |r| > 1): a damaged or forged table."""
    result = GateResult()
    df = table.df
    cand = df[df["metric"].isin(NON_NEGATIVE | MAY_BE_UNDEFINED) & df["axis"].isin(ERROR_AXES)]
    values = cand["value"].to_numpy(dtype=float)
    with np.errstate(invalid="ignore"):
        # a superset of the impossible values (negative, or beyond +-1): judged one by one
        suspect = (values < 0) | (np.abs(values) > 1) | np.isinf(values)
    cand = cand[suspect]
    for row in cand.to_dict("records"):
        why = _impossible(str(row["metric"]), str(row["axis"]), float(row["value"]))
        if why:
            result.violations.append(
                Violation(
                    ViolationKind.INVALID,
                    str(row["metric"]),
                    str(row["topic"]),
                    str(row["axis"]),
                    str(row["run"]),
                    _factor_dict(row, table.factors),
                    float(row["value"]),
                    math.nan,
                    "",
                    unit=str(row["unit"]),
                    note=why,
                )
            )
    return result


def check_log_warnings(table: ResultsTable, *, allow: bool = False) -> GateResult:
    """Runs whose logs a reader warned about (not closed cleanly, messages it could not use).

    The warnings travel as rows (``axis`` reference/other, metric ``n_warnings`` with the
    texts in ``note``, ``dropped.<cause>`` counts). They fail the gate unless ``allow``; then
    they are still listed, among the skipped values.
    """
    result = GateResult()
    df = table.df
    src = df[df["axis"].isin(SOURCES)]
    flagged = src[
        ((src["metric"] == "n_warnings") | src["metric"].str.startswith("dropped."))
        & (src["value"] > 0)
    ]
    for (run, topic, axis), grp in flagged.groupby(["run", "topic", "axis"], sort=False):
        texts = [str(n) for n in grp.loc[grp["metric"] == "n_warnings", "note"] if str(n)]
        drops = [
            f"{int(v)} message(s) dropped ({str(m).partition('.')[2]})"
            for m, v in zip(grp["metric"], grp["value"], strict=True)
            if str(m).startswith("dropped.")
        ]
        note = "; ".join(texts + drops)
        if allow:
            result.skipped.append(f"log warning {run}/{topic}/{axis}: {note} (allowed)")
            continue
        first = grp.iloc[0]
        result.violations.append(
            Violation(
                ViolationKind.LOG_WARNING,
                "log",
                str(topic),
                str(axis),
                str(run),
                _factor_dict(first.to_dict(), table.factors),
                math.nan,
                math.nan,
                "",
                rule="allow_log_warnings = false",
                note=note,
            )
        )
    return result


def check_runs(table: ResultsTable, expected: Sequence[str], source: str) -> GateResult:
    """Runs ``source`` (the manifest, the baseline) names that have no row in ``table``."""
    result = GateResult()
    have = set(table.runs)
    for run in dict.fromkeys(expected):
        if run not in have:
            result.violations.append(
                Violation(
                    ViolationKind.MISSING_RUN,
                    "",
                    "",
                    "",
                    str(run),
                    {},
                    math.nan,
                    math.nan,
                    "",
                    note=f"named by {source}",
                )
            )
    return result


def _validate_baseline(base: pd.DataFrame, tol: BaselineTolerance) -> None:
    """Refuse a baseline that cannot gate anything (ConfigError: exit 2)."""
    if base.empty:
        raise ConfigError(
            f"the baseline holds no rows of the gated metrics {list(tol.metrics)}: "
            "it cannot gate anything"
        )
    values = base["value"].astype(float)
    if not values.notna().any():
        raise ConfigError("every gated value of the baseline is NaN: it cannot gate anything")
    for row in base.to_dict("records"):
        metric, v = str(row["metric"]), float(row["value"])
        if math.isnan(v) and not _may_skip_undefined(metric, str(row["note"])):
            raise ConfigError(
                f"baseline {metric} {_where(row)} is NaN without a reason: "
                "a baseline must give every error metric"
            )
        why = _impossible(metric, str(row["axis"]), v)
        if why:
            raise ConfigError(f"baseline {metric} {_where(row)} = {v:.6g}: {why}")


def baseline_gaps(base: pd.DataFrame, tol: BaselineTolerance) -> GateResult:
    """A FAIL per gated metric (``tol.metrics``) that the baseline does not hold for every
    run/topic/axis it covers: such a value would pass unchecked (a baseline of Pearson r
    alone must not pass a run whose MAE regressed)."""
    result = GateResult()
    pose = base[base["axis"].isin(AXES)]
    keys = set(zip(pose["run"], pose["topic"], pose["axis"], strict=True))
    for metric in tol.metrics:
        rows = pose[pose["metric"] == metric]
        have = set(zip(rows["run"], rows["topic"], rows["axis"], strict=True))
        lacking = sorted(keys - have)
        if not lacking:
            continue
        if not have:
            note = f"the baseline holds no {metric} value ([baseline] metrics gates it)"
        else:
            first = "/".join(lacking[0])
            note = (
                f"the baseline lacks {metric} for {len(lacking)} of {len(keys)} "
                f"run/topic/axis values (e.g. {first})"
            )
        result.violations.append(
            Violation(
                ViolationKind.UNCOVERED,
                metric,
                "",
                "",
                "",
                {},
                math.nan,
                math.nan,
                "",
                rule="baseline",
                note=note,
            )
        )
    return result


def check_baseline(
    table: ResultsTable, baseline: ResultsTable, tolerance: BaselineTolerance | None = None
) -> GateResult:
    """Compare ``table`` with a golden ``baseline`` run by run (see the module doc)."""
    tol = tolerance or BaselineTolerance()
    key = ["run", "topic", "axis", "metric"]
    base = baseline.df[baseline.df["metric"].isin(tol.metrics)]
    _validate_baseline(base, tol)
    result = baseline_gaps(base, tol)
    # runs and topics of the results that the baseline does not cover would pass unchecked
    covered = set(zip(base["run"], base["topic"], strict=True))
    cur_pairs = table.df[table.df["metric"].isin(tol.metrics)][["run", "topic"]]
    for run, topic in dict.fromkeys(zip(cur_pairs["run"], cur_pairs["topic"], strict=True)):
        if (run, topic) not in covered:
            result.violations.append(
                Violation(
                    ViolationKind.UNGATED,
                    "",
                    str(topic),
                    "",
                    str(run),
                    {},
                    math.nan,
                    math.nan,
                    "",
                    rule="baseline",
                )
            )
    # a baseline run with no result at all: one failure, not one per value
    absent = [r for r in dict.fromkeys(base["run"]) if r not in set(table.runs)]
    result = result.merge(check_runs(table, absent, "the baseline"))
    base = base[~base["run"].isin(absent)]
    cur = table.df[[*key, "value", "note"]].rename(
        columns={"value": "_current_value", "note": "_current_note"}
    )
    merged = base.merge(cur, on=key, how="left", indicator=True)
    for row in merged.to_dict("records"):  # dicts: ~50x cheaper per row than iterrows
        b = float(row["value"])
        metric = str(row["metric"])
        unit = str(row["unit"]) or AXIS_UNITS.get(str(row["axis"]), "")
        common: dict[str, Any] = dict(
            metric=metric,
            topic=str(row["topic"]),
            axis=str(row["axis"]),
            run=str(row["run"]),
            factors=_factor_dict(row, baseline.factors),
            unit=unit,
            rule="baseline",
        )
        if row["_merge"] == "left_only":
            result.violations.append(
                Violation(ViolationKind.MISSING, value=math.nan, bound=b, op="", **common)
            )
            continue
        v = float(row["_current_value"])
        if math.isnan(b):  # _validate_baseline let only an undefined-by-definition value by
            result.skipped.append(f"{metric} {_where(row)}: undefined in the baseline")
            continue
        if metric in LOWER_IS_WORSE and b < tol.r_min:
            result.skipped.append(
                f"{metric} {_where(row)}: "
                f"baseline r {b:.3g} < r_min {tol.r_min:g} (noise-level axis)"
            )
            continue
        result.checked += 1
        if metric in LOWER_IS_WORSE:
            bound, op, bad = b - tol.atol_r, ">=", math.isnan(v) or v < b - tol.atol_r
        elif metric in ABS_IS_WORSE:
            bound = abs(b) * (1 + tol.rtol) + tol.atol(unit)
            op, bad = "|.| <=", math.isnan(v) or abs(v) > bound
        elif metric in HIGHER_IS_WORSE:
            bound = b * (1 + tol.rtol) + tol.atol(unit)
            op, bad = "<=", math.isnan(v) or v > bound
        elif math.isnan(v):  # informational metric: only its presence is checked
            bound, op, bad = b, "=", True
        else:
            continue
        if bad:
            kind = ViolationKind.UNDEFINED if math.isnan(v) else ViolationKind.BASELINE
            note = str(row["_current_note"]) if math.isnan(v) else ""
            result.violations.append(
                Violation(kind, value=v, bound=bound, op=op, note=note or "", **common)
            )
    return result


def baseline_from(
    table: ResultsTable,
    metrics: Sequence[str] = DEFAULT_BASELINE_METRICS,
    meta: Mapping[str, Any] | None = None,
) -> ResultsTable:
    """The rows a golden baseline needs (the gated metrics, every run/topic/axis)."""
    df = table.df[table.df["metric"].isin(list(metrics))]
    return ResultsTable.from_dataframe(df, table.factors, {**table.meta, **dict(meta or {})})
