"""The tidy results table: its rows, columns and files (CSV, JSON, Parquet).

Every compared run becomes rows of one long ("tidy") table with the columns

    run, topic, axis, metric, value, unit, note, <one column per experiment factor>

e.g. ``("force=10_torque=0", "model_rov_pose", "x", "mae", 0.0042, "m", "", 10.0, 0.0, ...)``.
Axes ``x y z`` are metres and ``roll pitch yaw`` degrees (ENU world / FLU body, ROS RPY);
``position_norm`` is the 3-D position error norm (m), ``rotation`` the geodesic angle (deg).
Other numeric fields of the compare JSON (alignment, clock offset, latency, counts, what the
log readers dropped or warned about) become rows too, with their JSON section as ``axis``
(:mod:`uwval.results.schema`). Undefined values (a Pearson r of a constant series) are kept
as NaN rows whose ``note`` says why, so the paper's three metrics (absolute error, MAE,
Pearson r) are always present for every axis.
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
from uwval.results.schema import (
    AXES,
    CORE_COLUMNS,
    PAPER_METRICS,
    as_json_obj,
    flatten_result,
    topic_results,
    unit_for,
)


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
            obj = as_json_obj(comparison)
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
                        "unit": unit_for(r.axis, r.metric),
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
            obj = read_json(p)
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


def read_json(path: Path) -> Any:
    """A JSON file's content; a file that is not JSON is a ConfigError naming it."""
    try:
        return json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{path}: not valid JSON: {exc}") from exc
