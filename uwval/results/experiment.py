"""Loading an experiment's results from wherever uwval wrote them: the manifest of a sweep
(``uwval simulate``), a batch ``comparisons.json``, a results table file or directory."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pandas as pd

from uwval.errors import ConfigError
from uwval.results.schema import SOURCES, as_json_obj, comparison_warnings
from uwval.results.table import ResultsTable, read_json


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
    obj = read_json(path)
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

    def run_warnings(self) -> dict[str, list[str]]:
        """Per run, the warnings of its comparison (all of them when the compare JSON is at
        hand; otherwise the log readers' warnings kept in the table). Runs without: absent."""
        out: dict[str, list[str]] = {}
        with_json = set()
        for run in self.runs:
            if run.comparison is not None:
                with_json.add(run.name)
                ws = comparison_warnings(run.comparison)
                if ws:
                    out[run.name] = ws
        df = self.table.df
        rows = df[
            df["axis"].isin(SOURCES)
            & (df["metric"] == "n_warnings")
            & (df["value"] > 0)
            & ~df["run"].isin(with_json)
        ]
        for run, note in zip(rows["run"], rows["note"], strict=True):
            texts = [t for t in str(note).split(" | ") if t]
            out[str(run)] = list(dict.fromkeys([*out.get(str(run), []), *texts]))
        return out


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
            run.comparison = as_json_obj(compare_logs(run.log, **opts))
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
            obj = read_json(p)
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
                comparisons = read_json(c)
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
        man_obj = read_json(man_path)
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
            run.comparison = as_json_obj(rec["comparison"])
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
