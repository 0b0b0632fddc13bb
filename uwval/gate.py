"""The CI gate: check a results table against thresholds and/or a golden baseline.

Thresholds live in a TOML file (format documented in ``THRESHOLDS_FORMAT`` and
``data/thresholds/default.toml``)::

    version = 1

    [[threshold]]
    name = "vehicle position MAE"      # optional, shown in the report
    metric = "mae"                     # a results-table metric (mae, max, rmse, p95, pearson_r...)
    axes = ["x", "y", "z"]             # default: all of x y z roll pitch yaw
    topics = ["model_rov_pose"]        # fnmatch patterns; default ["*"]
    max = 0.05                         # fail when value > max (units of the axis: m or deg)
    # min = 0.99                       # fail when value < min
    # factors = { current = 0.2 }      # only runs at these factor levels
    # undefined = "skip"               # NaN (e.g. Pearson r of a constant series): skip | fail

    [baseline]                         # tolerances for --baseline golden.json
    rtol = 0.25                        # relative slack on error metrics
    atol_m = 0.002                     # absolute slack, metres
    atol_deg = 0.05                    # absolute slack, degrees
    atol_r = 0.01                      # Pearson r may drop this much
    r_min = 0.9                        # baseline r below this (noise-level axis): not gated
    metrics = ["mae", "rmse", "max", "p95", "pearson_r"]

A rule that matches no row is itself a failure (a typo must not pass silently). Against a
baseline (a results table saved as JSON/CSV), error metrics regress when
``value > base * (1 + rtol) + atol``, Pearson r when ``value < base - atol_r``, bias when
``|value| > |base| * (1 + rtol) + atol``; a baseline r below ``r_min`` is not gated (an
axis that barely moves has a noise-level, meaningless correlation); a run, topic or axis
present in the baseline but missing from the results is a failure too.
"""

from __future__ import annotations

import fnmatch
import math
import sys
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pandas as pd

from uwval.errors import ConfigError
from uwval.results import AXES, AXIS_UNITS, ResultsTable

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python 3.10
    import tomli as tomllib

THRESHOLDS_FORMAT = __doc__ or ""

#: Metrics where larger is worse (errors); Pearson r is the one where smaller is worse.
HIGHER_IS_WORSE = frozenset({"mae", "rmse", "max", "p95", "std", "mean", "median", "sse"})
LOWER_IS_WORSE = frozenset({"pearson_r"})
ABS_IS_WORSE = frozenset({"bias"})
DEFAULT_BASELINE_METRICS: tuple[str, ...] = ("mae", "rmse", "max", "p95", "pearson_r")


@dataclass(frozen=True)
class ThresholdRule:
    """One bound on one metric over a set of topics/axes/factor levels."""

    metric: str
    axes: tuple[str, ...] = AXES
    topics: tuple[str, ...] = ("*",)
    max: float | None = None
    min: float | None = None
    factors: dict[str, Any] = field(default_factory=dict)
    undefined: str = "skip"
    name: str = ""

    def label(self) -> str:
        if self.name:
            return self.name
        parts = [self.metric]
        if self.max is not None:
            parts.append(f"<= {self.max:g}")
        if self.min is not None:
            parts.append(f">= {self.min:g}")
        return " ".join(parts)


@dataclass(frozen=True)
class BaselineTolerance:
    """Slack allowed against a golden baseline (see the module doc)."""

    rtol: float = 0.25
    atol_m: float = 0.002
    atol_deg: float = 0.05
    atol_r: float = 0.01
    #: Pearson r below this in the baseline is not gated: such a series is noise-level
    #: (an axis that barely moves), whose correlation is meaningless run to run.
    r_min: float = 0.9
    metrics: tuple[str, ...] = DEFAULT_BASELINE_METRICS

    def atol(self, unit: str) -> float:
        return {"m": self.atol_m, "deg": self.atol_deg}.get(unit, 0.0)


@dataclass(frozen=True)
class Thresholds:
    """A parsed thresholds file."""

    rules: tuple[ThresholdRule, ...] = ()
    baseline: BaselineTolerance = field(default_factory=BaselineTolerance)
    source: str = ""


@dataclass(frozen=True)
class Violation:
    """One thing that regressed: which value broke which bound, and where."""

    kind: str  # "threshold", "baseline", "missing", "undefined", "no-match"
    metric: str
    topic: str
    axis: str
    run: str
    factors: dict[str, Any]
    value: float
    bound: float
    op: str  # the relation that had to hold, e.g. "<=" or ">="
    unit: str = ""
    rule: str = ""

    def describe(self) -> str:
        levels = " ".join(f"{k}={_fmt_level(v)}" for k, v in self.factors.items())
        where = " ".join(
            p
            for p in (
                f"run={self.run}" if self.run else "",
                f"topic={self.topic}" if self.topic else "",
                f"axis={self.axis}" if self.axis else "",
                levels,
            )
            if p
        )
        unit = f" {self.unit}" if self.unit else ""
        if self.kind == "no-match":
            return f"rule [{self.rule}] matched no results ({where or 'any topic/axis'})"
        if self.kind == "missing":
            return (
                f"{self.metric} {where}: missing from the results (baseline {self.bound:.6g}{unit})"
            )
        if self.kind == "undefined":
            return (
                f"{self.metric} {where}: undefined (NaN), must be {self.op} "
                f"{self.bound:.6g}{unit} [{self.rule}]"
            )
        return (
            f"{self.metric} {where}: {self.value:.6g}{unit}, must be {self.op} "
            f"{self.bound:.6g}{unit} [{self.rule}]"
        )


@dataclass
class GateResult:
    """Outcome of :func:`check`: violations (empty = pass), counts of checked/skipped values."""

    violations: list[Violation] = field(default_factory=list)
    checked: int = 0
    skipped: list[str] = field(default_factory=list)

    @property
    def passed(self) -> bool:
        return not self.violations

    def format(self, limit: int | None = 200) -> str:
        """A readable multi-line verdict for terminals and CI logs."""
        head = (
            f"uwval check: PASS ({self.checked} values checked)"
            if self.passed
            else f"uwval check: FAIL - {len(self.violations)} regression(s) "
            f"among {self.checked} values checked"
        )
        lines = [head]
        shown = self.violations if limit is None else self.violations[:limit]
        lines += [f"  - {v.describe()}" for v in shown]
        if limit is not None and len(self.violations) > limit:
            lines.append(f"  ... and {len(self.violations) - limit} more")
        if self.skipped:
            lines.append(
                f"  ({len(self.skipped)} undefined value(s) skipped, e.g. {self.skipped[0]})"
            )
        return "\n".join(lines)

    def render(self) -> str:
        """The verdict as rich console markup (``format`` with colour)."""
        from rich.markup import escape

        text = escape(self.format())
        colour = "green" if self.passed else "red"
        first, _, rest = text.partition("\n")
        return f"[bold {colour}]{first}[/]" + (f"\n{rest}" if rest else "")

    def to_json(self) -> dict[str, Any]:
        """Machine-readable verdict: passed, checked, violations (with every field), skipped."""
        from dataclasses import asdict

        def clean(v: Any) -> Any:
            return None if isinstance(v, float) and not math.isfinite(v) else v

        return {
            "passed": self.passed,
            "checked": self.checked,
            "violations": [
                {k: clean(v) for k, v in asdict(x).items()} | {"message": x.describe()}
                for x in self.violations
            ],
            "skipped": list(self.skipped),
        }

    def merge(self, other: GateResult) -> GateResult:
        return GateResult(
            self.violations + other.violations,
            self.checked + other.checked,
            self.skipped + other.skipped,
        )


def _fmt_level(v: Any) -> str:
    if isinstance(v, float) and v.is_integer():
        return f"{v:g}"
    return f"{v:g}" if isinstance(v, float) else str(v)


# ----------------------------------------------------------------------------- parsing
def load_thresholds(path: str | Path) -> Thresholds:
    """Parse a thresholds TOML file; errors name the file and the offending rule."""
    p = Path(path)
    if p.is_dir():
        raise ConfigError(f"{p}: is a directory, not a thresholds TOML file")
    if not p.is_file():
        raise ConfigError(f"{p}: no such thresholds file")
    try:
        obj = tomllib.loads(p.read_text())
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{p}: not valid TOML: {exc}") from exc
    return parse_thresholds(obj, source=str(p))


def parse_thresholds(obj: Mapping[str, Any], source: str = "<thresholds>") -> Thresholds:
    """Build :class:`Thresholds` from the parsed TOML (or an equivalent dict)."""
    known = {"version", "threshold", "baseline", "description"}
    extra = sorted(set(obj) - known)
    if extra:
        raise ConfigError(f"{source}: unknown top-level key(s) {extra} (expected {sorted(known)})")
    version = obj.get("version", 1)
    if version != 1:
        raise ConfigError(f"{source}: unsupported thresholds version {version!r} (expected 1)")
    raw_rules = obj.get("threshold", [])
    if not isinstance(raw_rules, list):
        raise ConfigError(f"{source}: 'threshold' must be an array of tables ([[threshold]])")
    rules = tuple(_parse_rule(r, f"{source}: threshold #{i + 1}") for i, r in enumerate(raw_rules))
    base = obj.get("baseline", {})
    if not isinstance(base, Mapping):
        raise ConfigError(f"{source}: [baseline] must be a table")
    return Thresholds(rules, _parse_tolerance(base, f"{source}: [baseline]"), source)


def _parse_rule(r: Any, where: str) -> ThresholdRule:
    if not isinstance(r, Mapping):
        raise ConfigError(f"{where}: must be a table")
    allowed = {
        "name",
        "metric",
        "axis",
        "axes",
        "topic",
        "topics",
        "max",
        "min",
        "factors",
        "undefined",
    }
    extra = sorted(set(r) - allowed)
    if extra:
        raise ConfigError(f"{where}: unknown key(s) {extra} (allowed: {sorted(allowed)})")
    metric = r.get("metric")
    if not isinstance(metric, str) or not metric:
        raise ConfigError(f"{where}: 'metric' (a string, e.g. \"mae\") is required")
    axes = _str_list(r.get("axes", r.get("axis", list(AXES))), f"{where}: axes")
    topics = _str_list(r.get("topics", r.get("topic", ["*"])), f"{where}: topics")
    bounds = {}
    for key in ("max", "min"):
        v = r.get(key)
        if v is not None and (isinstance(v, bool) or not isinstance(v, (int, float))):
            raise ConfigError(f"{where}: '{key}' must be a number, got {v!r}")
        if v is not None and not math.isfinite(v):
            # a NaN bound compares false both ways: the rule would pass everything
            raise ConfigError(f"{where}: '{key}' must be a finite number, got {v!r}")
        bounds[key] = None if v is None else float(v)
    lo, hi = bounds["min"], bounds["max"]
    if hi is None and lo is None:
        raise ConfigError(f"{where} ({metric}): give 'max' and/or 'min'")
    if hi is not None and lo is not None and lo > hi:
        raise ConfigError(f"{where} ({metric}): 'min' {lo:g} is above 'max' {hi:g}")
    factors = r.get("factors", {})
    if not isinstance(factors, Mapping):
        raise ConfigError(f"{where}: 'factors' must be a table, e.g. {{ current = 0.2 }}")
    undefined = r.get("undefined", "skip")
    if undefined not in ("skip", "fail"):
        raise ConfigError(f'{where}: \'undefined\' must be "skip" or "fail"')
    name = r.get("name", "")
    return ThresholdRule(
        metric,
        tuple(axes),
        tuple(topics),
        bounds["max"],
        bounds["min"],
        dict(factors),
        undefined,
        str(name),
    )


def _str_list(v: Any, where: str) -> list[str]:
    if isinstance(v, str):
        return [v]
    if isinstance(v, list) and v and all(isinstance(x, str) for x in v):
        return list(v)
    raise ConfigError(f"{where}: must be a string or a non-empty list of strings")


def _parse_tolerance(base: Mapping[str, Any], where: str) -> BaselineTolerance:
    allowed = {"rtol", "atol_m", "atol_deg", "atol_r", "r_min", "metrics"}
    extra = sorted(set(base) - allowed)
    if extra:
        raise ConfigError(f"{where}: unknown key(s) {extra} (allowed: {sorted(allowed)})")
    vals: dict[str, Any] = {}
    for key in ("rtol", "atol_m", "atol_deg", "atol_r", "r_min"):
        if key in base:
            v = base[key]
            if isinstance(v, bool) or not isinstance(v, (int, float)) or v < 0:
                raise ConfigError(f"{where}: {key} must be a number >= 0, got {v!r}")
            vals[key] = float(v)
    if "metrics" in base:
        vals["metrics"] = tuple(_str_list(base["metrics"], f"{where}: metrics"))
    return BaselineTolerance(**vals)


# ----------------------------------------------------------------------------- checking
def _factor_dict(row: pd.Series, factors: Sequence[str]) -> dict[str, Any]:
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


def check_thresholds(table: ResultsTable, thresholds: Thresholds) -> GateResult:
    """Every rule against every matching row of ``table``."""
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
        want_topics = [t for t in topics if any(fnmatch.fnmatchcase(t, p) for p in rule.topics)]
        mask = (
            (df["metric"] == rule.metric)
            & df["axis"].isin(rule.axes)
            & df["topic"].isin(want_topics)
        )
        for f, level in rule.factors.items():
            mask &= df[f].map(lambda c, lv=level: _level_matches(c, lv))
        rows = df[mask]
        if rows.empty:
            result.violations.append(
                Violation(
                    "no-match",
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
        for _, row in rows.iterrows():
            value = float(row["value"])
            unit = str(row["unit"])
            fac = _factor_dict(row, table.factors)
            common: dict[str, Any] = dict(
                metric=rule.metric,
                topic=str(row["topic"]),
                axis=str(row["axis"]),
                run=str(row["run"]),
                factors=fac,
                unit=unit,
                rule=rule.label(),
            )
            result.checked += 1
            if math.isnan(value):
                if rule.undefined == "fail":
                    bound = rule.min if rule.min is not None else rule.max
                    op = ">=" if rule.min is not None else "<="
                    result.violations.append(
                        Violation(
                            "undefined", value=value, bound=float(bound or 0.0), op=op, **common
                        )
                    )
                else:
                    note = str(row["note"]) or "undefined"
                    result.skipped.append(
                        f"{rule.metric} {row['run']}/{row['topic']}/{row['axis']}: {note}"
                    )
                continue
            if rule.max is not None and value > rule.max:
                result.violations.append(
                    Violation("threshold", value=value, bound=rule.max, op="<=", **common)
                )
            if rule.min is not None and value < rule.min:
                result.violations.append(
                    Violation("threshold", value=value, bound=rule.min, op=">=", **common)
                )
    return result


def check_baseline(
    table: ResultsTable, baseline: ResultsTable, tolerance: BaselineTolerance | None = None
) -> GateResult:
    """Compare ``table`` with a golden ``baseline`` run by run (see the module doc)."""
    tol = tolerance or BaselineTolerance()
    key = ["run", "topic", "axis", "metric"]
    base = baseline.df[baseline.df["metric"].isin(tol.metrics)]
    cur = table.df[[*key, "value"]].rename(columns={"value": "_current_value"})
    merged = base.merge(cur, on=key, how="left", indicator=True)
    result = GateResult()
    for _, row in merged.iterrows():
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
            result.violations.append(Violation("missing", value=math.nan, bound=b, op="", **common))
            continue
        v = float(row["_current_value"])
        if math.isnan(b):
            result.skipped.append(
                f"{metric} {row['run']}/{row['topic']}/{row['axis']}: undefined in the baseline"
            )
            continue
        if metric in LOWER_IS_WORSE and b < tol.r_min:
            result.skipped.append(
                f"{metric} {row['run']}/{row['topic']}/{row['axis']}: "
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
        else:  # informational metric: only its presence is checked
            continue
        if bad:
            kind = "undefined" if math.isnan(v) else "baseline"
            result.violations.append(Violation(kind, value=v, bound=bound, op=op, **common))
    return result


def baseline_from(
    table: ResultsTable,
    metrics: Sequence[str] = DEFAULT_BASELINE_METRICS,
    meta: Mapping[str, Any] | None = None,
) -> ResultsTable:
    """The rows a golden baseline needs (the gated metrics, every run/topic/axis)."""
    df = table.df[table.df["metric"].isin(list(metrics))]
    return ResultsTable.from_dataframe(df, table.factors, {**table.meta, **dict(meta or {})})


def check(
    table: ResultsTable,
    thresholds: Thresholds | str | Path | None = None,
    baseline: ResultsTable | str | Path | None = None,
) -> GateResult:
    """The gate: thresholds and/or baseline (paths are loaded). At least one is required."""
    if thresholds is None and baseline is None:
        raise ConfigError("uwval check needs --thresholds FILE.toml and/or --baseline FILE.json")
    th = load_thresholds(thresholds) if isinstance(thresholds, (str, Path)) else thresholds
    if th is not None and not th.rules and baseline is None:
        # an empty rule list would pass every table: a gate that checks nothing is a mistake
        raise ConfigError(
            f"{th.source}: defines no threshold rules and no --baseline was given: nothing to check"
        )
    result = GateResult()
    if th is not None:
        result = result.merge(check_thresholds(table, th))
    if baseline is not None:
        base = ResultsTable.load(baseline) if isinstance(baseline, (str, Path)) else baseline
        tol = th.baseline if th is not None else BaselineTolerance()
        result = result.merge(check_baseline(table, base, tol))
    return result


#: Alias used by ``uwval demo``: the gate over an in-memory results table.
check_results = check
