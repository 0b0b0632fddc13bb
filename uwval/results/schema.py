"""Reading the compare JSON (the engine's one schema) into rows of the results table.

The compare JSON is made by :mod:`uwval.comparison.engine` (one topic pair,
``ComparisonResult.to_json``) and :mod:`uwval.comparison.logs` (a log: the vehicle pair at the
top level and every pair under ``topics``, keyed by the topic's short name). This module reads
exactly that schema; it does not guess between key aliases. Per axis the metrics are those of
:func:`uwval.comparison.stats.axis_stats` and ``pearson``: ``pearson_r`` may be null with a
``pearson_reason`` (a constant series): such a value is *undefined on purpose* and its row
keeps the reason in ``note``. Any other null is a value the engine could not compute; its row
is NaN with the note ``MISSING_NOTE``, which the gate fails.

What the log readers warned about (a log not closed cleanly, messages not used, by cause)
travels as rows too: ``axis`` = ``reference`` / ``other``, metric ``n_warnings`` (value: how
many, ``note``: the texts joined by `` | ``) and ``dropped.<cause>`` counts.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from uwval.comparison.engine import AXES as ENGINE_AXES
from uwval.errors import ConfigError

#: The pose axes, in the order every table and plot uses (the engine's own definition).
AXES: tuple[str, ...] = tuple(ENGINE_AXES)
POSITION_AXES: tuple[str, ...] = AXES[:3]
ROTATION_AXES: tuple[str, ...] = AXES[3:]
AXIS_UNITS: dict[str, str] = {
    "x": "m",
    "y": "m",
    "z": "m",
    "roll": "deg",
    "pitch": "deg",
    "yaw": "deg",
    "position_norm": "m",
    "rotation": "deg",
}
#: Units of the paper's experiment factors (applied force, torque, water current speed).
FACTOR_UNITS: dict[str, str] = {"force": "N", "torque": "N m", "current": "m/s"}

#: Per-axis metrics of the compare JSON contract (``pearson_ci`` is split into low/high).
AXIS_METRICS: tuple[str, ...] = (
    "mae",
    "rmse",
    "max",
    "p95",
    "bias",
    "std",
    "pearson_r",
    "pearson_p",
    "pearson_ci_low",
    "pearson_ci_high",
)
#: The paper's validation metrics: absolute error (summarised by its max and p95; the full
#: series is plotted per run), mean absolute error, and Pearson r. Always present per axis.
PAPER_METRICS: tuple[str, ...] = ("mae", "max", "pearson_r")
#: Metrics that the engine leaves undefined on purpose, with a ``pearson_reason`` (fewer than
#: 3 samples, a constant series). Every other metric must be a number.
MAY_BE_UNDEFINED: frozenset[str] = frozenset(
    {
        "pearson_r",
        "pearson_p",
        "pearson_ci_low",
        "pearson_ci_high",
        "pearson_n_eff",
        "pearson_ci_eff_low",
        "pearson_ci_eff_high",
    }
)
#: Interval fields of an axis ([low, high] in the JSON), split into ``<name>_low`` and
#: ``<name>_high`` rows.
INTERVAL_FIELDS: tuple[str, ...] = ("pearson_ci", "pearson_ci_eff")
#: Note of a NaN row whose value the compare JSON did not give (null or absent).
MISSING_NOTE = "missing: the compare JSON gives no number"
#: Columns every table has, before the factor columns.
CORE_COLUMNS: tuple[str, ...] = ("run", "topic", "axis", "metric", "value", "unit", "note")
#: The two sources of a comparison, as the compare JSON names their sections.
SOURCES: tuple[str, ...] = ("reference", "other")
#: Section of the compare JSON holding the geodesic rotation-angle statistics.
ROTATION_SECTION = "rotation_error_deg"

#: Count metrics of an axis (no unit): the number of samples Pearson r was computed on.
COUNT_METRICS: frozenset[str] = frozenset({"pearson_n", "pearson_n_eff"})
#: Text fields of an axis that are not metrics: the reason Pearson r is undefined is carried
#: in the ``note`` of the undefined rows, never as a row of its own.
TEXT_FIELDS: frozenset[str] = frozenset({"pearson_reason"})

_UNITLESS_METRICS = MAY_BE_UNDEFINED | COUNT_METRICS


def factor_label(factor: str) -> str:
    """A factor's name with its unit for axis labels and table headers: ``force (N)``.

    User factors without a known unit keep their bare name.
    """
    unit = FACTOR_UNITS.get(factor)
    return f"{factor} ({unit})" if unit else factor


def as_json_obj(comparison: Any) -> dict[str, Any]:
    """A LogComparison / ComparisonResult object, its JSON text or its parsed dict -> dict."""
    if isinstance(comparison, Mapping):
        return dict(comparison)
    if isinstance(comparison, (str, bytes)):
        try:
            obj = json.loads(comparison)
        except json.JSONDecodeError as exc:
            raise ConfigError(f"comparison JSON is not valid JSON: {exc}") from exc
        if not isinstance(obj, dict):
            raise ConfigError("comparison JSON must be an object")
        return obj
    to_json = getattr(comparison, "to_json", None)
    if callable(to_json):
        return as_json_obj(to_json())
    raise ConfigError(
        f"cannot read comparison results from a {type(comparison).__name__} "
        "(expected a LogComparison, a ComparisonResult, or their JSON)"
    )


def _number(v: Any) -> float | None:
    if isinstance(v, bool) or v is None:
        return None
    if isinstance(v, (int, float, np.integer, np.floating)):
        return float(v)
    return None


def topic_results(obj: Mapping[str, Any]) -> list[tuple[str, dict[str, Any]]]:
    """Split one compare JSON into ``(topic, ComparisonResult JSON)`` pairs.

    A LogComparison JSON carries every pair under ``topics`` (topic short name -> result);
    its top level repeats the vehicle pair and is not read twice. A single ComparisonResult
    JSON (``axes`` at the top, no ``topics``) is one pair named after its reference topic.
    """
    topics = obj.get("topics")
    if topics is not None:
        if not isinstance(topics, Mapping) or not topics:
            raise ConfigError("comparison JSON: 'topics' must be a non-empty object")
        out = []
        for name, res in topics.items():
            if not isinstance(res, Mapping) or "axes" not in res:
                raise ConfigError(f"comparison JSON: topics.{name} has no 'axes'")
            out.append((short_topic(str(name)), dict(res)))
        return out
    if "axes" in obj:
        ref = obj.get("reference")
        name = ref.get("topic") if isinstance(ref, Mapping) else None
        return [(short_topic(name) if isinstance(name, str) else "", dict(obj))]
    raise ConfigError(
        "comparison JSON has neither 'axes' (one topic pair) nor per-topic results under "
        f"'topics'; keys present: {sorted(obj)}"
    )


def short_topic(name: str) -> str:
    """``/gazebo/model_rov_pose`` -> ``model_rov_pose``: one name for both sides of a pair."""
    parts = [p for p in name.split("/") if p]
    if len(parts) >= 2 and parts[0] in ("gazebo", "unity"):
        return "/".join(parts[1:])
    return name.strip("/") or name


def unit_for(axis: str, metric: str) -> str:
    """The unit of one row (m, deg, s, ms...; empty for counts and unitless metrics)."""
    if metric in _UNITLESS_METRICS or metric.startswith(("n_", "dropped.")):
        return ""
    if metric.endswith("_count"):
        return ""
    if metric == "sse":
        return "m^2" if axis == "position_norm" else ""
    if axis in AXIS_UNITS:
        return AXIS_UNITS[axis]
    if axis == "lag":
        return _lag_unit(metric)
    for suffix, unit in (
        ("_ppm", "ppm"),
        ("_ns", "ns"),
        ("_ms", "ms"),
        ("_s", "s"),
        ("_m", "m"),
        ("_deg", "deg"),
        ("_hz", "Hz"),
    ):
        if metric.endswith(suffix):
            return unit
    return ""


def _lag_unit(metric: str) -> str:
    """Units of the compare JSON's ``lag`` section (uwval.comparison.lag): seconds for the
    lag and its CI, the axis's unit per second for ``speed.<axis>``, the axis's unit for
    ``residual.<axis>.<stat>``; none for fractions and counts."""
    parts = metric.split(".")
    if parts[0] == "speed" and len(parts) == 2 and parts[1] in AXIS_UNITS:
        return f"{AXIS_UNITS[parts[1]]}/s"
    if parts[0] == "residual" and len(parts) == 3 and parts[1] in AXIS_UNITS:
        return AXIS_UNITS[parts[1]]
    if metric.endswith(("_s", "_s_low", "_s_high")):
        return "s"
    return ""


@dataclass(frozen=True)
class Row:
    """One flattened value of a compare JSON: (axis, metric, value, note)."""

    axis: str
    metric: str
    value: float
    note: str = ""


def flatten_result(res: Mapping[str, Any]) -> list[Row]:
    """One ComparisonResult JSON -> rows (axis, metric, value, note); see the module doc."""
    rows: list[Row] = []
    axes = res.get("axes")
    if not isinstance(axes, Mapping):
        raise ConfigError("comparison JSON: 'axes' must be an object of per-axis metrics")
    for axis in AXES:
        a = axes.get(axis)
        if not isinstance(a, Mapping):
            raise ConfigError(f"comparison JSON: axes.{axis} is missing")
        reason = a.get("pearson_reason")
        reason = reason if isinstance(reason, str) and reason else ""
        seen: set[str] = set()

        def note_for(metric: str, reason: str = reason) -> str:
            return reason if metric in MAY_BE_UNDEFINED and reason else MISSING_NOTE

        for metric, v in a.items():
            if metric in TEXT_FIELDS:
                continue
            if metric in INTERVAL_FIELDS:
                pair = v if isinstance(v, (list, tuple)) and len(v) == 2 else (None, None)
                for m, x in zip((f"{metric}_low", f"{metric}_high"), pair, strict=True):
                    num = _number(x)
                    rows.append(
                        Row(
                            axis,
                            m,
                            math.nan if num is None else num,
                            "" if num is not None else note_for(m),
                        )
                    )
                    seen.add(m)
                continue
            num = _number(v)
            if num is not None:
                rows.append(Row(axis, metric, num))
                seen.add(metric)
            elif v is None:
                rows.append(Row(axis, metric, math.nan, note_for(metric)))
                seen.add(metric)
        for metric in PAPER_METRICS:  # the paper's metrics are always present
            if metric not in seen:
                rows.append(Row(axis, metric, math.nan, note_for(metric)))
    norm = res.get("position_error_norm")
    if isinstance(norm, Mapping):
        rows += _flatten_section("position_norm", norm)
    rot = res.get(ROTATION_SECTION)
    if isinstance(rot, Mapping):
        rows += _flatten_section("rotation", rot)
    for src in SOURCES:
        info = res.get(src)
        if isinstance(info, Mapping):
            rows += _source_rows(src, info)
    for key, value in res.items():
        if key in ("axes", "position_error_norm", ROTATION_SECTION, *SOURCES):
            continue
        num = _number(value)
        if num is not None:
            rows.append(Row("", key, num))
        elif isinstance(value, Mapping):
            rows += _flatten_section(key, value)
    return rows


def _source_rows(src: str, info: Mapping[str, Any]) -> list[Row]:
    """Rows of one source: its numbers, what the reader dropped and what it warned about."""
    rows = _flatten_section(src, {k: v for k, v in info.items() if k != "warnings"})
    warnings = info.get("warnings")
    texts = [str(w) for w in warnings] if isinstance(warnings, list) else []
    rows.append(Row(src, "n_warnings", float(len(texts)), " | ".join(texts)))
    return rows


def _flatten_section(axis: str, sect: Mapping[str, Any], prefix: str = "") -> list[Row]:
    rows: list[Row] = []
    for key, v in sect.items():
        name = f"{prefix}{key}"
        num = _number(v)
        if num is not None:
            rows.append(Row(axis, name, num))
        elif isinstance(v, Mapping):
            rows += _flatten_section(axis, v, prefix=f"{name}.")
        elif (
            isinstance(v, (list, tuple)) and len(v) == 2 and all(_number(x) is not None for x in v)
        ):
            rows.append(Row(axis, f"{name}_low", float(v[0])))
            rows.append(Row(axis, f"{name}_high", float(v[1])))
    return rows


def comparison_warnings(obj: Mapping[str, Any]) -> list[str]:
    """Every warning of one compare JSON (its top level and each topic's), each once, in order.

    These include what the log readers reported (a log not closed cleanly, messages not used),
    which the engine copies into each result's ``warnings``.
    """
    found: list[str] = []
    sections = [obj, *(v for v in (obj.get("topics") or {}).values() if isinstance(v, Mapping))]
    for sect in sections:
        ws = sect.get("warnings")
        if isinstance(ws, list):
            found += [str(w) for w in ws]
    return list(dict.fromkeys(found))
