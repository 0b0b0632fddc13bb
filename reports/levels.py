"""Pass or fail at a glance: per threshold rule, and per rule at every factor level.

The verdicts come from the gate's own violations (:func:`uwval.gate.check`), so the report
cannot disagree with ``uwval check``; the worst value shown beside each verdict is taken from
the same rows the rule gated (the rule's metric, axes, topics or roles and factor filter).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
import pandas as pd

from uwval.gate import GateResult, ThresholdRule, Thresholds
from uwval.gate.verdict import ViolationKind
from uwval.reports.content import Table
from uwval.reports.numbers import Quantity, fmt, fmt_level, quantity_of, unit_suffix
from uwval.results import ResultsTable, factor_label, factor_levels

PASS, FAIL = "PASS", "FAIL"


@dataclass(frozen=True)
class RuleScope:
    """The rows one rule gates, with the quantity its values are shown as."""

    rule: ThresholdRule
    rows: pd.DataFrame
    quantity: Quantity

    def worst(self, rows: pd.DataFrame | None = None) -> tuple[float, str]:
        """(worst value, its run) over ``rows`` (default: all the rule's rows); NaN, ''
        when none is finite. Worst: the largest for a ``max`` rule, the smallest for ``min``."""
        sub = self.rows if rows is None else rows
        vals = sub["value"].to_numpy(dtype=float)
        ok = np.isfinite(vals)
        if not ok.any():
            return math.nan, ""
        pick = np.nanargmax if self.rule.max is not None else np.nanargmin
        i = int(pick(np.where(ok, vals, np.nan)))
        return float(vals[i]), str(sub["run"].iloc[i])

    def header(self) -> str:
        """The rule as a column header: its name and its bound, in the shown unit."""
        return f"{self.rule.label()} {self.bound()}"

    def bound(self) -> str:
        """The bound in the shown unit: "≤ 20.00 mm", "≥ 0.9990"."""
        unit = unit_suffix(self.quantity).strip(" ()")
        bounds = []
        if self.rule.max is not None:
            bounds.append(f"≤ {fmt(self.rule.max, self.quantity)}")
        if self.rule.min is not None:
            bounds.append(f"≥ {fmt(self.rule.min, self.quantity)}")
        return " and ".join(bounds) + (f" {unit}" if unit else "")


def rule_scopes(table: ResultsTable, thresholds: Thresholds) -> list[RuleScope]:
    """The rows each rule of ``thresholds`` gates in ``table`` (as the gate selects them)."""
    from uwval.gate.checks import _level_matches

    df = table.df
    out = []
    for rule in thresholds.rules:
        topics = [t for t in table.topics if rule.applies_to(t)]
        mask = (df["metric"] == rule.metric) & df["axis"].isin(rule.axes) & df["topic"].isin(topics)
        for f, level in rule.factors.items():
            if f in df.columns:
                mask &= df[f].map(lambda c, lv=level: _level_matches(c, lv))
        rows = df[mask]
        units = set(rows["unit"].astype(str)) or {""}
        quantity = quantity_of(rule.metric, units.pop() if len(units) == 1 else "")
        out.append(RuleScope(rule, rows, quantity))
    return out


def _failed_runs(gate: GateResult) -> dict[str, set[str]]:
    """rule label -> runs with a violation of it (threshold, undefined or no-match kinds)."""
    kinds = {ViolationKind.THRESHOLD, ViolationKind.UNDEFINED, ViolationKind.NO_MATCH}
    out: dict[str, set[str]] = {}
    for v in gate.violations:
        if v.kind in kinds:
            out.setdefault(v.rule, set()).add(v.run)
    return out


def _other_failures(gate: GateResult) -> dict[str, list[str]]:
    """run -> kinds of its non-rule failures (baseline, log warnings, missing, invalid...)."""
    out: dict[str, list[str]] = {}
    skip = {ViolationKind.THRESHOLD, ViolationKind.UNDEFINED, ViolationKind.NO_MATCH}
    for v in gate.violations:
        if v.kind not in skip:
            out.setdefault(v.run, []).append(v.kind.value)
    return out


def _cell(scope: RuleScope, rows: pd.DataFrame, failed: set[str]) -> tuple[str, bool]:
    """A level's cell for one rule: verdict and worst value; (text, passed)."""
    if rows.empty:
        return "not gated", True
    bad = "" in failed or bool(failed & set(rows["run"]))
    worst, _ = scope.worst(rows)
    return f"{FAIL if bad else PASS} {fmt(worst, scope.quantity)}", not bad


def rules_table(
    scopes: Sequence[RuleScope], gate: GateResult, run_ids: Mapping[str, str] | None = None
) -> Table:
    """One row per threshold rule: what it gates, its bound, the worst value and where,
    values checked, PASS or FAIL. ``run_ids``: the short run labels of the runs table."""
    failed = _failed_runs(gate)
    ids = dict(run_ids or {})
    t = Table(
        "Threshold rules",
        ["rule", "metric", "axes", "topics", "bound", "worst", "worst run", "values", "verdict"],
        [],
        caption="Each rule of the thresholds file; worst: the value closest to breaking the "
        "bound (largest for a maximum, smallest for a minimum) over every run it gates; "
        "worst run: as labelled in the runs table.",
    )
    for s in scopes:
        worst, run = s.worst()
        bad = s.rule.label() in failed
        where = ", ".join(s.rule.roles) if s.rule.roles else ", ".join(s.rule.topics)
        t.rows.append(
            [
                s.rule.label(),
                s.rule.metric,
                ", ".join(s.rule.axes),
                where,
                s.bound(),
                fmt(worst, s.quantity) + unit_suffix(s.quantity).replace("(", "").replace(")", ""),
                ids.get(run, run) or "n/a",
                str(len(s.rows)),
                FAIL if bad else PASS,
            ]
        )
        t.flags[(len(t.rows) - 1, 8)] = "bad" if bad else "good"
    return t


def level_table(
    table: ResultsTable, scopes: Sequence[RuleScope], gate: GateResult, baseline: bool
) -> Table | None:
    """Rows: every level of every factor (and all runs); columns: every rule, and the
    baseline and other checks. A cell: PASS/FAIL and the worst value at that level."""
    levels = factor_levels(table)
    if not levels and not scopes:
        return None
    failed = _failed_runs(gate)
    others = _other_failures(gate)
    columns = ["factor = level", "runs", *[s.header() for s in scopes]]
    if baseline or others:
        columns.append("baseline and other checks")
    t = Table(
        "Pass or fail per factor level",
        columns,
        [],
        caption="Each cell: the verdict of one threshold rule over the runs at that level, "
        "and the worst value there (unit in the column header). The last column counts the "
        "runs at the level that fail another check (baseline regression, reader warnings, "
        "missing or impossible values).",
    )
    run_factors = table.run_factors()
    groups: list[tuple[str, list[str]]] = [("all runs", list(table.runs))]
    for f, lvls in levels.items():
        col = run_factors[f] if f in run_factors.columns else pd.Series(dtype=object)
        for lv in lvls:
            runs = [str(r) for r in col.index[col.map(lambda c, lv=lv: _same(c, lv))]]
            unit = factor_label(f).removeprefix(f).strip(" ()")
            label = f"{f} = {fmt_level(lv)}" + (f" {unit}" if unit else "")
            groups.append((label, runs))
    for label, runs in groups:
        row = [label, str(len(runs))]
        r = len(t.rows)
        for k, s in enumerate(scopes):
            text, ok = _cell(s, s.rows[s.rows["run"].isin(runs)], failed.get(s.rule.label(), set()))
            row.append(text)
            t.flags[(r, 2 + k)] = "good" if ok else "bad"
        if len(columns) > 2 + len(scopes):
            bad_runs = [x for x in runs if x in others]
            extra = [x for x in others.get("", [])]  # failures not tied to a run
            n_bad = len(bad_runs) + (1 if extra and label == "all runs" else 0)
            row.append(f"{FAIL} ({n_bad} run(s))" if n_bad else PASS)
            t.flags[(r, len(columns) - 1)] = "bad" if n_bad else "good"
        t.rows.append(row)
    return t


def _same(cell: object, level: object) -> bool:
    if isinstance(level, (int, float)) and not isinstance(level, bool):
        try:
            return math.isclose(float(cell), float(level), rel_tol=1e-9, abs_tol=1e-12)  # type: ignore[arg-type]
        except (TypeError, ValueError):
            return False
    return str(cell) == str(level)
