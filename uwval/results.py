"""The tidy results table of an experiment, and its analysis per factor level.

Every compared run becomes rows of one long ("tidy") table with the columns

    run, topic, axis, metric, value, unit, note, <one column per experiment factor>

e.g. ``("force=10_torque=0", "model_rov_pose", "x", "mae", 0.0042, "m", "", 10.0, 0.0, ...)``.
Axes ``x y z`` are metres and ``roll pitch yaw`` degrees (ENU world / FLU body, ROS RPY);
``position_norm`` is the 3-D position error norm (m), ``rotation`` the geodesic angle (deg).
Other numeric fields of the compare JSON (alignment, clock offset, latency, counts) become
rows too, with their JSON section as ``axis``. Undefined values (a Pearson r of a constant
series) are kept as NaN rows whose ``note`` says why, so the paper's three metrics (absolute
error, MAE, Pearson r) are always present for every axis.

The analysis functions (summaries per level, main effects, one-way ANOVA, two-way tables)
work on the table and return pandas DataFrames; the report builder plots them.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from uwval.errors import ConfigError

#: The pose axes, in the order every table and plot uses.
AXES: tuple[str, ...] = ("x", "y", "z", "roll", "pitch", "yaw")
POSITION_AXES: tuple[str, ...] = ("x", "y", "z")
ROTATION_AXES: tuple[str, ...] = ("roll", "pitch", "yaw")
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


def factor_label(factor: str) -> str:
    """A factor's name with its unit for axis labels and table headers: ``force (N)``.

    User factors without a known unit keep their bare name.
    """
    unit = FACTOR_UNITS.get(factor)
    return f"{factor} ({unit})" if unit else factor


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
#: Columns every table has, before the factor columns.
CORE_COLUMNS: tuple[str, ...] = ("run", "topic", "axis", "metric", "value", "unit", "note")

_UNITLESS_METRICS = {"pearson_r", "pearson_p", "pearson_ci_low", "pearson_ci_high"}


# ----------------------------------------------------------------------------- flattening
def _as_json_obj(comparison: Any) -> dict[str, Any]:
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
        return _as_json_obj(to_json())
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

    Accepts a LogComparison JSON, whose per-topic results sit under ``topics`` (a mapping
    topic -> result, or a list of results carrying ``topic``/``name``; preferred when present,
    as its top level repeats the vehicle topic), or a single ComparisonResult JSON (``axes``).
    """
    for key in ("topics", "results", "comparisons", "pairs"):
        sect = obj.get(key)
        if isinstance(sect, Mapping):
            out = []
            for name, res in sect.items():
                if isinstance(res, Mapping) and "axes" in res:
                    out.append((_topic_name(res, str(name)), dict(res)))
            if out:
                return out
        if isinstance(sect, list):
            out = [
                (_topic_name(r, f"topic{i}"), dict(r))
                for i, r in enumerate(sect)
                if isinstance(r, Mapping) and "axes" in r
            ]
            if out:
                return out
    if "axes" in obj:
        return [(_topic_name(obj, ""), dict(obj))]
    raise ConfigError(
        "comparison JSON has neither 'axes' (one topic pair) nor per-topic results under "
        f"'topics'; keys present: {sorted(obj)}"
    )


def _topic_name(res: Mapping[str, Any], default: str) -> str:
    for key in ("name", "topic", "pair", "label"):
        v = res.get(key)
        if isinstance(v, str) and v:
            return _short_topic(v)
    for key in ("reference_topic", "gazebo_topic"):
        v = res.get(key)
        if isinstance(v, str) and v:
            return _short_topic(v)
    return _short_topic(default)


def _short_topic(name: str) -> str:
    """``/gazebo/model_rov_pose`` -> ``model_rov_pose``: one name for both sides of a pair."""
    parts = [p for p in name.split("/") if p]
    if len(parts) >= 2 and parts[0] in ("gazebo", "unity"):
        return "/".join(parts[1:])
    return name.strip("/") or name


def _unit_for(axis: str, metric: str) -> str:
    if metric in _UNITLESS_METRICS or metric.startswith("n_") or metric.endswith("_count"):
        return ""
    if metric == "sse":
        return "m^2" if axis == "position_norm" else ""
    if axis in AXIS_UNITS:
        return AXIS_UNITS[axis]
    for suffix, unit in (
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


@dataclass(frozen=True)
class _Row:
    axis: str
    metric: str
    value: float
    note: str = ""


def flatten_result(res: Mapping[str, Any]) -> list[_Row]:
    """One ComparisonResult JSON -> rows (axis, metric, value, note); see the module doc."""
    rows: list[_Row] = []
    axes = res.get("axes")
    if not isinstance(axes, Mapping):
        raise ConfigError("comparison JSON: 'axes' must be an object of per-axis metrics")
    for axis in AXES:
        a = axes.get(axis)
        if not isinstance(a, Mapping):
            raise ConfigError(f"comparison JSON: axes.{axis} is missing")
        reason = ""
        for key in ("pearson_reason", "pearson_r_reason", "pearson_note", "reason"):
            if isinstance(a.get(key), str):
                reason = a[key]
                break
        seen: set[str] = set()
        for metric, v in a.items():
            if metric == "pearson_ci":
                lo, hi = v if isinstance(v, (list, tuple)) and len(v) == 2 else (None, None)
                for m, x in (("pearson_ci_low", lo), ("pearson_ci_high", hi)):
                    num = _number(x)
                    rows.append(
                        _Row(
                            axis,
                            m,
                            math.nan if num is None else num,
                            "" if num is not None else reason or "undefined",
                        )
                    )
                    seen.add(m)
                continue
            num = _number(v)
            if num is not None:
                rows.append(_Row(axis, metric, num))
                seen.add(metric)
            elif v is None:
                rows.append(_Row(axis, metric, math.nan, reason or "undefined"))
                seen.add(metric)
        for metric in PAPER_METRICS:  # the paper's metrics are always present
            if metric not in seen:
                rows.append(_Row(axis, metric, math.nan, reason or "not reported"))
    norm = res.get("position_error_norm")
    if isinstance(norm, Mapping):
        rows += _flatten_section("position_norm", norm)
    for key, value in res.items():
        if key in ("axes", "position_error_norm"):
            continue
        num = _number(value)
        if num is not None:
            rows.append(_Row("", key, num))
        elif isinstance(value, Mapping):
            axis = (
                "rotation"
                if key
                in (
                    "rotation",
                    "rotation_error",
                    "rotation_angle",
                    "geodesic",
                    "rotation_error_deg",
                )
                else key
            )
            rows += _flatten_section(axis, value)
    return rows


def _flatten_section(axis: str, sect: Mapping[str, Any], prefix: str = "") -> list[_Row]:
    rows: list[_Row] = []
    for key, v in sect.items():
        name = f"{prefix}{key}"
        num = _number(v)
        if num is not None:
            rows.append(_Row(axis, name, num))
        elif isinstance(v, Mapping):
            rows += _flatten_section(axis, v, prefix=f"{name}.")
        elif (
            isinstance(v, (list, tuple)) and len(v) == 2 and all(_number(x) is not None for x in v)
        ):
            rows.append(_Row(axis, f"{name}_low", float(v[0])))
            rows.append(_Row(axis, f"{name}_high", float(v[1])))
    return rows


# ----------------------------------------------------------------------------- the table
@dataclass
class ResultsTable:
    """The tidy results of one or more compared runs (see the module doc for the columns).

    Attributes:
        df: the long table; one row per (run, topic, axis, metric).
        factors: names of the factor columns, in experiment order.
        meta: provenance (uwval version, inputs, options); saved with JSON output.
    """

    df: pd.DataFrame
    factors: list[str] = field(default_factory=list)
    meta: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        missing = [c for c in CORE_COLUMNS if c not in self.df.columns]
        if missing:
            raise ConfigError(f"results table lacks column(s) {missing}")
        for f in self.factors:
            if f not in self.df.columns:
                raise ConfigError(f"results table lacks the factor column {f!r}")
            if f in CORE_COLUMNS:
                raise ConfigError(f"factor name {f!r} clashes with a results column")

    # -------------------------------------------------------------- construction
    @classmethod
    def from_comparisons(
        cls,
        items: Iterable[tuple[str, Mapping[str, Any] | None, Any]],
        *,
        meta: Mapping[str, Any] | None = None,
    ) -> ResultsTable:
        """Build the table from ``(run_name, factors, LogComparison-or-its-JSON)`` triples.

        ``factors`` maps factor name -> level (numbers or strings); runs may lack a factor
        (its cell is NaN). The comparison may be a LogComparison/ComparisonResult object
        (anything with ``to_json()``), its JSON text, or the parsed dict.
        """
        records: list[dict[str, Any]] = []
        factor_names: list[str] = []
        runs_seen: set[str] = set()
        for run, factors, comparison in items:
            if run in runs_seen:
                raise ConfigError(f"run name {run!r} appears twice in the results")
            runs_seen.add(run)
            fac = dict(factors or {})
            for name in fac:
                if name in CORE_COLUMNS:
                    raise ConfigError(f"run {run!r}: factor {name!r} clashes with a column")
                if name not in factor_names:
                    factor_names.append(name)
            obj = _as_json_obj(comparison)
            for topic, res in topic_results(obj):
                try:
                    flat = flatten_result(res)
                except ConfigError as exc:
                    raise ConfigError(f"run {run!r}, topic {topic!r}: {exc}") from exc
                for r in flat:
                    rec: dict[str, Any] = {
                        "run": run,
                        "topic": topic,
                        "axis": r.axis,
                        "metric": r.metric,
                        "value": r.value,
                        "unit": _unit_for(r.axis, r.metric),
                        "note": r.note,
                    }
                    rec.update(fac)
                    records.append(rec)
        df = pd.DataFrame.from_records(records, columns=[*CORE_COLUMNS, *factor_names])
        return cls(_normalise(df, factor_names), factor_names, dict(meta or {}))

    @classmethod
    def from_dataframe(
        cls,
        df: pd.DataFrame,
        factors: Sequence[str] | None = None,
        meta: Mapping[str, Any] | None = None,
    ) -> ResultsTable:
        """Wrap a long DataFrame; factors default to every non-core column."""
        names = (
            list(factors)
            if factors is not None
            else [c for c in df.columns if c not in CORE_COLUMNS]
        )
        return cls(_normalise(df.copy(), names), names, dict(meta or {}))

    def to_dataframe(self) -> pd.DataFrame:
        """A copy of the long table (pandas)."""
        return self.df.copy()

    def concat(self, other: ResultsTable) -> ResultsTable:
        """Rows of both tables (runs must not repeat)."""
        dup = set(self.runs) & set(other.runs)
        if dup:
            raise ConfigError(f"run(s) {sorted(dup)} are in both results tables")
        names = self.factors + [f for f in other.factors if f not in self.factors]
        df = pd.concat([self.df, other.df], ignore_index=True)
        return ResultsTable(_normalise(df, names), names, {**self.meta, **other.meta})

    # -------------------------------------------------------------- views
    @property
    def runs(self) -> list[str]:
        return list(dict.fromkeys(self.df["run"]))

    @property
    def topics(self) -> list[str]:
        return list(dict.fromkeys(self.df["topic"]))

    def run_factors(self) -> pd.DataFrame:
        """One row per run: its factor levels (index: run)."""
        if not self.factors:
            return pd.DataFrame(index=pd.Index(self.runs, name="run"))
        return self.df.groupby("run", sort=False)[self.factors].first()

    def varying_factors(self) -> list[str]:
        """Factors that take more than one level across the runs."""
        rf = self.run_factors()
        return [f for f in self.factors if rf[f].nunique(dropna=True) > 1]

    def select(
        self,
        *,
        metric: str | Sequence[str] | None = None,
        axis: str | Sequence[str] | None = None,
        topic: str | Sequence[str] | None = None,
        run: str | Sequence[str] | None = None,
    ) -> pd.DataFrame:
        """Rows matching every given filter (each a value or a list of values)."""
        mask = pd.Series(True, index=self.df.index)
        for col, want in (("metric", metric), ("axis", axis), ("topic", topic), ("run", run)):
            if want is None:
                continue
            values = [want] if isinstance(want, str) else list(want)
            mask &= self.df[col].isin(values)
        return self.df[mask]

    def value(self, run: str, topic: str, axis: str, metric: str) -> float:
        """One cell; raises ConfigError naming the key when it is absent."""
        rows = self.select(run=run, topic=topic, axis=axis, metric=metric)
        if rows.empty:
            raise ConfigError(
                f"no result for run={run!r} topic={topic!r} axis={axis!r} metric={metric!r}"
            )
        return float(rows["value"].iloc[0])

    def wide(
        self, metrics: Sequence[str] = PAPER_METRICS, axes: Sequence[str] = AXES
    ) -> pd.DataFrame:
        """Runs x (topic, axis, metric) matrix of values, factors first: the report's table."""
        sub = self.select(metric=list(metrics), axis=list(axes))
        if sub.empty:
            return pd.DataFrame()
        wide = sub.pivot_table(
            index="run",
            columns=["topic", "axis", "metric"],
            values="value",
            aggfunc="first",
            dropna=False,
            sort=False,
        )
        return wide.reindex(self.runs)

    # -------------------------------------------------------------- files
    def save(self, path: str | Path) -> list[Path]:
        """Write the table; returns the files written.

        A path ending in ``.csv``, ``.json`` or ``.parquet`` (needs pyarrow) writes that one
        file; any other path is taken as a directory and receives ``results.csv``,
        ``results.json`` and, when pyarrow is importable, ``results.parquet``.
        """
        p = Path(path)
        suffix = p.suffix.lower()
        if suffix not in (".csv", ".json", ".parquet"):
            if p.exists() and not p.is_dir():
                raise ConfigError(
                    f"{p}: unknown results format {suffix!r} "
                    "(use .csv, .json, .parquet or a directory)"
                )
            return self.save_all(p)
        if suffix == ".parquet" and not parquet_available():
            raise ConfigError(f"{p}: writing Parquet needs pyarrow (pip install pyarrow)")
        try:
            p.parent.mkdir(parents=True, exist_ok=True)
            if suffix == ".csv":
                self.df.to_csv(p, index=False, float_format="%.17g")
            elif suffix == ".json":
                p.write_text(json.dumps(self.to_json_obj(), indent=1, allow_nan=False) + "\n")
            else:
                self.df.to_parquet(p, index=False)
        except OSError as exc:
            raise ConfigError(
                f"{p}: cannot write the results table: {exc.strerror or exc}"
            ) from exc
        return [p]

    def save_all(self, directory: str | Path, stem: str = "results") -> list[Path]:
        """Write CSV and JSON (and Parquet when pyarrow is importable) into ``directory``."""
        d = Path(directory)
        out = self.save(d / f"{stem}.csv") + self.save(d / f"{stem}.json")
        if parquet_available():
            out += self.save(d / f"{stem}.parquet")
        return out

    def to_json_obj(self) -> dict[str, Any]:
        """``{"format": "uwval-results", "version": 1, "factors", "meta", "rows"}``; NaN -> null."""
        rows = []
        for rec in self.df.to_dict(orient="records"):
            rows.append({k: _json_cell(v) for k, v in rec.items()})
        return {
            "format": "uwval-results",
            "version": 1,
            "factors": list(self.factors),
            "meta": _json_safe(self.meta),
            "rows": rows,
        }

    @classmethod
    def load(cls, path: str | Path) -> ResultsTable:
        """Read a table written by :meth:`save` (CSV, JSON or Parquet)."""
        p = Path(path)
        if p.is_dir():
            raise ConfigError(f"{p}: is a directory, not a results file (.csv, .json, .parquet)")
        if not p.is_file():
            raise ConfigError(f"{p}: no such results file")
        suffix = p.suffix.lower()
        if suffix == ".csv":
            try:
                # text columns stay text: a run named "007" is not the number 7, and an
                # all-empty note column is not float NaN
                text_cols = dict.fromkeys(("run", "topic", "axis", "metric", "unit", "note"), str)
                df = pd.read_csv(p, keep_default_na=False, na_values=[""], dtype=text_cols)
            except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError) as exc:
                reason = " ".join(str(exc).split())
                raise ConfigError(f"{p}: not a readable results CSV: {reason}") from exc
            try:
                return cls.from_dataframe(df)
            except ConfigError as exc:
                raise ConfigError(f"{p}: {exc}") from exc
        if suffix == ".json":
            obj = _read_json(p)
            try:
                return cls.from_json_obj(obj)
            except ConfigError as exc:
                raise ConfigError(f"{p}: {exc}") from exc
        if suffix == ".parquet":
            if not parquet_available():
                raise ConfigError(f"{p}: reading Parquet needs pyarrow (pip install pyarrow)")
            try:
                df = pd.read_parquet(p)
            except (OSError, ValueError) as exc:  # pyarrow's ArrowInvalid is a ValueError
                raise ConfigError(f"{p}: not a readable Parquet file: {exc}") from exc
            try:
                return cls.from_dataframe(df)
            except ConfigError as exc:
                raise ConfigError(f"{p}: {exc}") from exc
        raise ConfigError(f"{p}: unknown results format {suffix!r}")

    @classmethod
    def from_json_obj(cls, obj: Any) -> ResultsTable:
        """Inverse of :meth:`to_json_obj`."""
        if not isinstance(obj, dict) or obj.get("format") != "uwval-results":
            raise ConfigError('not a uwval results JSON (expected "format": "uwval-results")')
        factors = obj.get("factors") or []
        rows = obj.get("rows")
        if not isinstance(rows, list):
            raise ConfigError("results JSON: 'rows' must be a list")
        df = pd.DataFrame.from_records(rows, columns=[*CORE_COLUMNS, *factors])
        return cls(_normalise(df, list(factors)), list(factors), dict(obj.get("meta") or {}))

    def __len__(self) -> int:
        return len(self.df)


def parquet_available() -> bool:
    """True when pandas can write Parquet (pyarrow importable)."""
    try:
        import pyarrow  # noqa: F401
    except ImportError:
        return False
    return True


def _normalise(df: pd.DataFrame, factors: Sequence[str]) -> pd.DataFrame:
    df = df.reset_index(drop=True)
    for col in ("run", "topic", "axis", "metric", "unit", "note"):
        if col in df.columns:
            df[col] = df[col].fillna("").astype(str)
    if "value" in df.columns:
        value = pd.to_numeric(df["value"], errors="coerce").astype(np.float64)
        # empty / None / "nan" are undefined values (e.g. Pearson r of a constant series);
        # any other text is a damaged table, not an undefined metric
        text = df["value"].astype(str).str.strip().str.lower()
        bad = value.isna() & df["value"].notna() & ~text.isin(["", "nan", "none", "null"])
        if bad.any():
            i = int(np.flatnonzero(bad.to_numpy())[0])
            row = df.iloc[i]
            raise ConfigError(
                f"row {i + 1} ({row.get('run', '?')} {row.get('topic', '?')} "
                f"{row.get('axis', '?')} {row.get('metric', '?')}): value "
                f"{df['value'].iloc[i]!r} is not a number"
            )
        df["value"] = value
    for f in factors:
        if f in df.columns:
            num = pd.to_numeric(df[f], errors="coerce")
            # numeric factors stay numeric (sortable levels); mixed/strings stay as they are
            if num.notna().sum() == df[f].notna().sum():
                df[f] = num.astype(np.float64)
    return df


def _json_cell(v: Any) -> Any:
    if isinstance(v, (float, np.floating)):
        return None if not math.isfinite(float(v)) else float(v)
    if isinstance(v, np.integer):
        return int(v)
    return v


def _json_safe(obj: Any) -> Any:
    if isinstance(obj, Mapping):
        return {str(k): _json_safe(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_json_safe(v) for v in obj]
    return _json_cell(obj)


# ----------------------------------------------------------------------------- analysis
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


# ----------------------------------------------------------------------------- experiments
@dataclass(frozen=True)
class ManifestRun:
    """One run of an experiment manifest (``uwval simulate`` output)."""

    name: str
    log: Path
    factors: dict[str, Any]
    seed: int | None
    bridge: dict[str, Any]


def read_manifest(
    results_dir: str | Path, name: str = "manifest.json"
) -> tuple[dict[str, Any], list[ManifestRun]]:
    """Read ``DIR/manifest.json`` -> (experiment dict, runs); log paths resolved against DIR."""
    d = Path(results_dir)
    path = d / name
    if not path.is_file():
        raise ConfigError(f"{d}: no manifest.json (not an experiment results directory)")
    obj = _read_json(path)
    runs_obj = obj.get("runs") if isinstance(obj, dict) else None
    if not isinstance(runs_obj, list):
        raise ConfigError(f"{path}: 'runs' must be a list")
    runs = []
    for i, r in enumerate(runs_obj):
        if not isinstance(r, dict) or not isinstance(r.get("name"), str):
            raise ConfigError(f"{path}: runs[{i}] needs a string 'name'")
        log = Path(str(r.get("log", "")))
        runs.append(
            ManifestRun(
                name=r["name"],
                log=log if log.is_absolute() else d / log,
                factors=dict(r.get("factors") or {}),
                seed=r.get("seed"),
                bridge=dict(r.get("bridge") or {}),
            )
        )
    return dict(obj.get("experiment") or {}), runs


# ----------------------------------------------------------------------------- loading inputs
@dataclass
class RunRecord:
    """One run of an experiment: its log, factor levels, bridge statistics, compare JSON."""

    name: str
    log: Path | None
    factors: dict[str, Any]
    bridge: dict[str, Any] = field(default_factory=dict)
    comparison: dict[str, Any] | None = None
    seed: int | None = None


@dataclass
class ExperimentResults:
    """Everything a report or the gate reads from a results location.

    Attributes:
        table: the tidy results table.
        runs: per run (manifest order): log, factors, bridge stats, comparison JSON if known.
        manifest: the parsed ``manifest.json`` when one was found.
        sources: the files read (for the provenance section).
        failed: runs the simulation or the comparison reported as failed.
    """

    table: ResultsTable
    runs: list[RunRecord]
    manifest: dict[str, Any] | None = None
    sources: list[Path] = field(default_factory=list)
    failed: list[dict[str, Any]] = field(default_factory=list)


def compare_pending(
    exp: ExperimentResults, options: Mapping[str, Any] | None = None
) -> ExperimentResults:
    """Compare the logs of runs that have no comparison yet (a manifest without results).

    Runs whose log is missing or cannot be compared are added to ``failed`` (with the cause)
    while the others are compared; the table is rebuilt from all runs.
    """
    from uwval.comparison import compare_logs
    from uwval.errors import UwvalError

    opts = dict(options or {})
    for run in exp.runs:
        if run.comparison is not None:
            continue
        if run.log is None or not run.log.exists():
            exp.failed.append({"name": run.name, "error": f"log {run.log} is missing"})
            continue
        try:
            run.comparison = _as_json_obj(compare_logs(run.log, **opts))
        except UwvalError as exc:
            exp.failed.append({"name": run.name, "error": str(exc)})
            continue
        if run.log not in exp.sources:
            exp.sources.append(run.log)
    exp.table = ResultsTable.from_comparisons(
        [(r.name, r.factors, r.comparison) for r in exp.runs if r.comparison is not None],
        meta=exp.table.meta,
    )
    return exp


def _read_json(path: Path) -> Any:
    try:
        return json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{path}: not valid JSON: {exc}") from exc


def _is_comparisons_obj(obj: Any) -> bool:
    runs = obj.get("runs") if isinstance(obj, dict) else None
    return isinstance(runs, list) and all(isinstance(r, dict) and "comparison" in r for r in runs)


def _is_manifest_obj(obj: Any) -> bool:
    runs = obj.get("runs") if isinstance(obj, dict) else None
    return isinstance(runs, list) and not _is_comparisons_obj(obj)


def load_experiment_results(
    path: str | Path, manifest: str | Path | None = None
) -> ExperimentResults:
    """Read results from wherever ``uwval`` wrote them.

    ``path`` may be a results table file (``results.csv/.json/.parquet``), a batch
    ``comparisons.json``, a results directory holding those, or an experiment directory
    (``manifest.json`` + ``results/``). The manifest (given, or found next to the results or
    one level up) adds log paths and bridge statistics. When only a manifest exists (logs
    not compared yet) the runs have no comparison and the table is empty: the caller runs
    the batch compare (``uwval.batch.compare_batch``) first.
    """
    p = Path(path)
    if not p.exists():
        raise ConfigError(f"{p}: no such results file or directory")
    sources: list[Path] = []
    table: ResultsTable | None = None
    comparisons: dict[str, Any] | None = None
    man_path: Path | None = Path(manifest) if manifest is not None else None
    if p.is_file():
        if p.suffix.lower() == ".json":
            obj = _read_json(p)
            if _is_comparisons_obj(obj):
                comparisons = obj
            elif _is_manifest_obj(obj):
                man_path = man_path or p
            else:
                table = ResultsTable.load(p)
        else:
            table = ResultsTable.load(p)
        sources.append(p)
        search_dirs = [p.parent, p.parent.parent]
    else:
        search_dirs = [p, p / "results", p.parent]
        for d in search_dirs[:2]:
            c = d / "comparisons.json"
            if comparisons is None and c.is_file():
                comparisons = _read_json(c)
                if not _is_comparisons_obj(comparisons):
                    raise ConfigError(
                        f'{c}: expected {{"runs": [{{name, factors, comparison}}, ...]}}'
                    )
                sources.append(c)
            for name in ("results.json", "results.csv", "results.parquet"):
                f = d / name
                if table is None and comparisons is None and f.is_file():
                    table = ResultsTable.load(f)
                    sources.append(f)
    if man_path is None:
        for d in search_dirs:
            if (d / "manifest.json").is_file():
                man_path = d / "manifest.json"
                break
    man_obj: dict[str, Any] | None = None
    runs: list[RunRecord] = []
    failed: list[dict[str, Any]] = []
    if man_path is not None:
        _, mruns = read_manifest(man_path.parent, man_path.name)
        man_obj = _read_json(man_path)
        if man_path not in sources:
            sources.append(man_path)
        failed += list((man_obj or {}).get("failed") or [])
        runs = [
            RunRecord(r.name, r.log, dict(r.factors), dict(r.bridge), None, r.seed) for r in mruns
        ]
    by_name = {r.name: r for r in runs}
    if comparisons is not None:
        failed += list(comparisons.get("failed") or [])
        for rec in comparisons["runs"]:
            name = str(rec.get("name", ""))
            run = by_name.get(name)
            if run is None:
                log = rec.get("log")
                run = RunRecord(
                    name,
                    Path(log) if log else None,
                    dict(rec.get("factors") or {}),
                    dict(rec.get("bridge") or {}),
                )
                runs.append(run)
                by_name[name] = run
            run.comparison = _as_json_obj(rec["comparison"])
            if rec.get("bridge") and not run.bridge:
                run.bridge = dict(rec["bridge"])
        table = ResultsTable.from_comparisons(
            [(r.name, r.factors, r.comparison) for r in runs if r.comparison is not None]
        )
    if table is None:
        if not runs:
            raise ConfigError(f"{p}: found no results table, comparisons.json or manifest.json")
        table = ResultsTable.from_comparisons([])
    if not runs:  # a bare table: runs from its rows
        rf = table.run_factors()
        runs = [
            RunRecord(str(name), None, {str(k): v for k, v in row.items() if pd.notna(v)})
            for name, row in rf.iterrows()
        ]
    return ExperimentResults(table, runs, man_obj, sources, failed)
