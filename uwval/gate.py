"""The CI gate: check a results table against thresholds and/or a golden baseline.

Thresholds live in a TOML file (format documented in ``THRESHOLDS_FORMAT`` and
``data/thresholds/default.toml``)::

    version = 1
    # allow_log_warnings = false       # a run whose log a reader warned about (not closed
                                       # cleanly, messages dropped) fails unless true

    [[threshold]]
    name = "vehicle position MAE"      # optional, shown in the report
    metric = "mae"                     # a results-table metric (mae, max, rmse, p95, pearson_r...)
    axes = ["x", "y", "z"]             # default: all of x y z roll pitch yaw
    topics = ["model_rov_pose"]        # fnmatch patterns; default ["*"]
    max = 0.05                         # fail when value > max (units of the axis: m or deg)
    # min = 0.99                       # fail when value < min
    # factors = { current = 0.2 }      # only runs at these factor levels
    # undefined = "skip"               # Pearson r undefined with the engine's reason
                                       # (a constant series): skip | fail

    [baseline]                         # tolerances for --baseline golden.json
    rtol = 0.25                        # relative slack on error metrics
    atol_m = 0.002                     # absolute slack, metres
    atol_deg = 0.05                    # absolute slack, degrees
    atol_r = 0.01                      # Pearson r may drop this much
    r_min = 0.9                        # baseline r below this (noise-level axis): not gated
    metrics = ["mae", "rmse", "max", "p95", "pearson_r"]

A rule that matches no row is itself a failure (a typo must not pass silently), and so is a
run the rule should cover (by its factor levels) that has no row for one of its axes.
A gated value that is NaN or missing fails, unless it may be undefined by definition: a
Pearson statistic the engine left undefined with its reason (fewer than 3 samples, a
constant series), which a rule's ``undefined = "skip"`` (the default) skips, reason shown.
An impossible value (a negative MAE/RMSE/max/p95/std, |r| > 1) fails. A run that a reader
warned about (a log not closed cleanly, messages dropped) fails unless ``allow_log_warnings``.
Runs of the manifest without results fail. Against a
baseline (a results table saved as JSON/CSV), error metrics regress when
``value > base * (1 + rtol) + atol``, Pearson r when ``value < base - atol_r``, bias when
``|value| > |base| * (1 + rtol) + atol``; a baseline r below ``r_min`` is not gated (an
axis that barely moves has a noise-level, meaningless correlation); a run, topic or axis
present in the baseline but missing from the results is a failure too, as is a run or topic
of the results the baseline does not cover. A baseline that holds no gated value, or an error
metric that is NaN or negative, is refused (exit 2): it cannot gate anything.
"""

from __future__ import annotations

import fnmatch
import math
import sys
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from enum import Enum
from pathlib import Path
from typing import Any

import pandas as pd

from uwval.errors import ConfigError
from uwval.results import AXES, AXIS_UNITS, MAY_BE_UNDEFINED, MISSING_NOTE, ResultsTable
from uwval.results.schema import SOURCES

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
#: Metrics that cannot be negative (statistics of absolute errors, spreads, norms).
NON_NEGATIVE = frozenset({"mae", "rmse", "max", "p95", "std", "median", "sse", "min", "mean"})
#: Axes whose statistics :data:`NON_NEGATIVE` applies to.
ERROR_AXES = frozenset({*AXES, "position_norm", "rotation"})


class ViolationKind(str, Enum):
    """Why the gate failed on one value, run or rule."""

    THRESHOLD = "threshold"  # a value broke a rule's bound
    BASELINE = "baseline"  # a value regressed against the golden baseline
    MISSING = "missing"  # a baseline value is absent from the results
    MISSING_RUN = "missing-run"  # a run of the manifest or the baseline has no results
    UNDEFINED = "undefined"  # a gated value is NaN / null with no rule allowing it
    INVALID = "invalid"  # an impossible value (negative MAE, |r| > 1)
    NO_MATCH = "no-match"  # a rule matched no row (or none of one run's)
    UNGATED = "ungated"  # a run/topic of the results the baseline does not cover
    LOG_WARNING = "log-warning"  # a reader warned about the run's log

    def __str__(self) -> str:
        return self.value


class UndefinedPolicy(str, Enum):
    """What a rule does with a Pearson statistic the engine left undefined (with its reason)."""

    SKIP = "skip"
    FAIL = "fail"

    def __str__(self) -> str:
        return self.value


@dataclass(frozen=True)
class ThresholdRule:
    """One bound on one metric over a set of topics/axes/factor levels."""

    metric: str
    axes: tuple[str, ...] = AXES
    topics: tuple[str, ...] = ("*",)
    max: float | None = None
    min: float | None = None
    factors: dict[str, Any] = field(default_factory=dict)
    undefined: UndefinedPolicy = UndefinedPolicy.SKIP
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
    #: False (default): a run whose log a reader warned about fails the gate.
    allow_log_warnings: bool = False


@dataclass(frozen=True)
class Violation:
    """One thing that regressed: which value broke which bound, and where."""

    kind: ViolationKind
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
    note: str = ""

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
        K = ViolationKind
        why = f" ({self.note})" if self.note else ""
        if self.kind is K.NO_MATCH:
            return f"rule [{self.rule}] matched no results ({where or 'any topic/axis'}){why}"
        if self.kind is K.MISSING:
            return (
                f"{self.metric} {where}: missing from the results (baseline {self.bound:.6g}{unit})"
            )
        if self.kind is K.MISSING_RUN:
            return f"{where}: the run is missing from the results{why}"
        if self.kind is K.UNGATED:
            return f"{where}: not covered by the baseline, so not gated{why}"
        if self.kind is K.LOG_WARNING:
            return f"{where}: the log reader warned: {self.note} [{self.rule}]"
        if self.kind is K.INVALID:
            return f"{self.metric} {where}: {self.value:.6g}{unit} is impossible{why}"
        if self.kind is K.UNDEFINED:
            return (
                f"{self.metric} {where}: undefined (NaN){why}, must be {self.op} "
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
        allowed = [x for x in self.skipped if x.startswith("log warning ")]
        undefined = [x for x in self.skipped if not x.startswith("log warning ")]
        lines += [f"  ! {x}" for x in allowed]  # allowed, never hidden
        if undefined:
            lines.append(f"  ({len(undefined)} undefined value(s) skipped, e.g. {undefined[0]})")
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
                {k: clean(v) for k, v in asdict(x).items()}
                | {"kind": x.kind.value, "message": x.describe()}
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
    known = {"version", "threshold", "baseline", "description", "allow_log_warnings"}
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
    allow = obj.get("allow_log_warnings", False)
    if not isinstance(allow, bool):
        raise ConfigError(f"{source}: allow_log_warnings must be true or false, got {allow!r}")
    return Thresholds(rules, _parse_tolerance(base, f"{source}: [baseline]"), source, allow)


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
    try:
        undefined = UndefinedPolicy(r.get("undefined", UndefinedPolicy.SKIP.value))
    except ValueError:
        raise ConfigError(f'{where}: \'undefined\' must be "skip" or "fail"') from None
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


def _where(row: pd.Series) -> str:
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
        want_topics = [t for t in topics if any(fnmatch.fnmatchcase(t, p) for p in rule.topics)]
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
        for _, row in rows.iterrows():
            value = float(row["value"])
            unit = str(row["unit"])
            note = str(row["note"])
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
                if rule.undefined is UndefinedPolicy.SKIP and _may_skip_undefined(
                    rule.metric, note
                ):
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
                    Violation(
                        ViolationKind.THRESHOLD, value=value, bound=rule.max, op="<=", **common
                    )
                )
            if rule.min is not None and value < rule.min:
                result.violations.append(
                    Violation(
                        ViolationKind.THRESHOLD, value=value, bound=rule.min, op=">=", **common
                    )
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
    for _, row in cand.iterrows():
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
                _factor_dict(first, table.factors),
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
    for _, row in base.iterrows():
        metric, v = str(row["metric"]), float(row["value"])
        if math.isnan(v) and not _may_skip_undefined(metric, str(row["note"])):
            raise ConfigError(
                f"baseline {metric} {_where(row)} is NaN without a reason: "
                "a baseline must give every error metric"
            )
        why = _impossible(metric, str(row["axis"]), v)
        if why:
            raise ConfigError(f"baseline {metric} {_where(row)} = {v:.6g}: {why}")


def check_baseline(
    table: ResultsTable, baseline: ResultsTable, tolerance: BaselineTolerance | None = None
) -> GateResult:
    """Compare ``table`` with a golden ``baseline`` run by run (see the module doc)."""
    tol = tolerance or BaselineTolerance()
    key = ["run", "topic", "axis", "metric"]
    base = baseline.df[baseline.df["metric"].isin(tol.metrics)]
    _validate_baseline(base, tol)
    result = GateResult()
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


def check(
    table: ResultsTable,
    thresholds: Thresholds | str | Path | None = None,
    baseline: ResultsTable | str | Path | None = None,
    *,
    expected_runs: Sequence[str] = (),
) -> GateResult:
    """The gate: thresholds and/or baseline (paths are loaded). At least one is required.

    Besides the rules and the baseline, every gate run also fails impossible values
    (:func:`check_values`), runs whose logs a reader warned about unless the thresholds allow
    it (:func:`check_log_warnings`) and ``expected_runs`` (e.g. the manifest's) that have no
    results (:func:`check_runs`).
    """
    if thresholds is None and baseline is None:
        raise ConfigError("uwval check needs --thresholds FILE.toml and/or --baseline FILE.json")
    th = load_thresholds(thresholds) if isinstance(thresholds, (str, Path)) else thresholds
    if th is not None and not th.rules and baseline is None:
        # an empty rule list would pass every table: a gate that checks nothing is a mistake
        raise ConfigError(
            f"{th.source}: defines no threshold rules and no --baseline was given: nothing to check"
        )
    if table.df.empty:
        raise ConfigError("the results hold no rows: nothing to check")
    result = check_values(table)
    result = result.merge(check_runs(table, expected_runs, "the manifest"))
    allow = th.allow_log_warnings if th is not None else False
    result = result.merge(check_log_warnings(table, allow=allow))
    if th is not None:
        result = result.merge(check_thresholds(table, th))
    if baseline is not None:
        base = ResultsTable.load(baseline) if isinstance(baseline, (str, Path)) else baseline
        tol = th.baseline if th is not None else BaselineTolerance()
        result = result.merge(check_baseline(table, base, tol))
    return result


#: Alias used by ``uwval demo``: the gate over an in-memory results table.
check_results = check
