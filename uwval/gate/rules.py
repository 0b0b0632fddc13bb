"""The thresholds file of the gate: its rules, baseline tolerances and parsing (format in
:mod:`uwval.gate`)."""

from __future__ import annotations

import math
import sys
from collections.abc import Mapping
from dataclasses import dataclass, field
from enum import Enum
from pathlib import Path
from typing import Any

from uwval.errors import ConfigError
from uwval.results import AXES

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python 3.10
    import tomli as tomllib


#: Metrics where larger is worse (errors); Pearson r is the one where smaller is worse.
HIGHER_IS_WORSE = frozenset({"mae", "rmse", "max", "p95", "std", "mean", "median", "sse"})
LOWER_IS_WORSE = frozenset({"pearson_r"})
ABS_IS_WORSE = frozenset({"bias"})
DEFAULT_BASELINE_METRICS: tuple[str, ...] = ("mae", "rmse", "max", "p95", "pearson_r")
#: Metrics that cannot be negative (statistics of absolute errors, spreads, norms).
NON_NEGATIVE = frozenset({"mae", "rmse", "max", "p95", "std", "median", "sse", "min", "mean"})
#: Axes whose statistics :data:`NON_NEGATIVE` applies to.
ERROR_AXES = frozenset({*AXES, "position_norm", "rotation"})


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
    #: Roles the rule applies to (``vehicle``, ``camera``); empty: by ``topics`` only. A
    #: role-keyed rule that finds no topic of its role is skipped, never a failure: results
    #: are not judged by how their topics are named.
    roles: tuple[str, ...] = ()

    def applies_to(self, topic: str) -> bool:
        """Whether ``topic`` (a results-table topic label) is in this rule's scope."""
        import fnmatch

        if not any(fnmatch.fnmatchcase(topic, p) for p in self.topics):
            return False
        return not self.roles or topic_role(topic) in self.roles

    def label(self) -> str:
        if self.name:
            return self.name
        parts = [self.metric]
        if self.max is not None:
            parts.append(f"<= {self.max:g}")
        if self.min is not None:
            parts.append(f">= {self.min:g}")
        return " ".join(parts)


#: Roles a rule may be keyed by (``any`` = every role).
ROLES = ("vehicle", "camera")


def topic_role(topic: str) -> str:
    """The role of a compared topic pair from its label: ``camera`` when the label names a
    camera (``gui_camera_pose``, ``/camera/pose``...), else ``vehicle`` (the tracked body:
    ``model_rov_pose``, ``tethys/pose``, ``groundtruth~ORB-SLAM``)."""
    return "camera" if "camera" in topic.lower() else "vehicle"


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
        "role",
        "roles",
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
    roles: list[str] = []
    if "roles" in r or "role" in r:
        roles = _str_list(r.get("roles", r.get("role")), f"{where}: roles")
        bad = sorted(set(roles) - {*ROLES, "any"})
        if bad:
            raise ConfigError(
                f"{where}: unknown role(s) {bad}; choose from {', '.join((*ROLES, 'any'))}"
            )
        roles = list(ROLES) if "any" in roles else roles
    return ThresholdRule(
        metric,
        tuple(axes),
        tuple(topics),
        bounds["max"],
        bounds["min"],
        dict(factors),
        undefined,
        str(name),
        tuple(roles),
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
