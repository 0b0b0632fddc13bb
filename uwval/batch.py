"""Batch compare: every log of an experiment directory (or manifest) into one results table.

A task is one whole log, so a batch runs on any executor of :mod:`uwval.executors` (process
pool or Dask distributed) and gives the same table either way. A log that fails to compare
is reported with its run name and cause while the others complete.

Security: a manifest is data, and may come from anywhere. Its logs are read as local paths;
a URL (``s3://``, ``ftp://``, ``http://``...) is fetched only when the user allowed its
protocol themselves (``compare --batch --allow-protocol s3``, or the environment variable
``UWVAL_ALLOW_PROTOCOLS=s3,gs``), never because a manifest names it.
"""

from __future__ import annotations

import json
import os
from collections.abc import Collection
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from uwval.errors import ConfigError
from uwval.executors import Executor, run_tasks

LOG_SUFFIXES = (".mcap", ".bag", ".db3")

#: Environment variable naming the remote protocols a batch may fetch (comma-separated).
ALLOW_PROTOCOLS_ENV = "UWVAL_ALLOW_PROTOCOLS"


def allowed_protocols(extra: Collection[str] = ()) -> frozenset[str]:
    """Protocols the user allowed: ``extra`` (the command line) plus ``UWVAL_ALLOW_PROTOCOLS``."""
    env = os.environ.get(ALLOW_PROTOCOLS_ENV, "")
    names = [*extra, *env.split(",")]
    return frozenset(n.strip().lower().removesuffix("://") for n in names if n.strip())


def url_protocols(log: str) -> list[str]:
    """Every protocol of a (possibly chained, ``simplecache::s3://b/k``) fsspec URL."""
    return [part.partition("://")[0].lower() for part in log.split("::")]


def check_remote_allowed(log: str, allowed: Collection[str], where: str) -> None:
    """Refuse a URL unless every protocol of it is in ``allowed`` (named by the user)."""
    refused = [p for p in url_protocols(log) if p not in allowed]
    if refused:
        raise ConfigError(
            f"{where}: log {log!r} is remote ({', '.join(refused)}); uwval reads local paths "
            "unless you allow a protocol yourself (compare --batch --allow-protocol "
            f"{refused[0]}, or {ALLOW_PROTOCOLS_ENV}={refused[0]})"
        )


@dataclass(frozen=True)
class BatchItem:
    """One log to compare, with the factor levels of its run."""

    name: str
    log: str
    factors: dict[str, Any] = field(default_factory=dict)
    options: dict[str, Any] = field(default_factory=dict)
    bridge: dict[str, Any] = field(default_factory=dict)
    #: remote protocols the user allowed (a URL log with another protocol is refused)
    allow: frozenset[str] = frozenset()


def items_from(
    source: Path, options: dict[str, Any] | None = None, *, allow: Collection[str] = ()
) -> list[BatchItem]:
    """Batch items from a manifest.json, a directory holding one, or a directory of logs.

    A manifest's URL logs are refused (:class:`ConfigError`) unless their protocols are in
    ``allow`` or ``UWVAL_ALLOW_PROTOCOLS``: a file's contents alone never make uwval fetch.
    """
    opts = dict(options or {})
    allowed = allowed_protocols(allow)
    manifest = source if source.is_file() else source / "manifest.json"
    if manifest.is_file():
        try:
            data = json.loads(manifest.read_text())
        except json.JSONDecodeError as exc:
            raise ConfigError(f"{manifest}: not valid JSON: line {exc.lineno}: {exc.msg}") from exc
        base = manifest.parent
        runs = data.get("runs")
        if not isinstance(runs, list):
            raise ConfigError(f"{manifest}: no 'runs' list")
        items = []
        for i, r in enumerate(runs):
            if "name" not in r or "log" not in r:
                raise ConfigError(f"{manifest}: run {i} lacks 'name' or 'log'")
            log = str(r["log"])
            if is_url(log):
                check_remote_allowed(log, allowed, f"{manifest}: run {i} ({r['name']})")
            elif not Path(log).is_absolute():
                log = str(base / log)
            items.append(
                BatchItem(
                    r["name"],
                    log,
                    dict(r.get("factors", {})),
                    opts,
                    dict(r.get("bridge", {})),
                    allowed,
                )
            )
        return items
    if source.is_dir():
        logs = sorted(
            p
            for p in source.rglob("*")
            if p.is_file()
            and p.suffix in LOG_SUFFIXES
            and not (p.parent / "metadata.yaml").exists()  # files of a rosbag2 directory
        )
        bag_dirs = sorted(p.parent for p in source.rglob("metadata.yaml"))
        found = logs + bag_dirs
        if not found:
            raise ConfigError(f"{source}: no manifest.json and no logs (.mcap, .bag, rosbag2)")
        return [BatchItem(p.stem if p.is_file() else p.name, str(p), {}, opts) for p in found]
    raise ConfigError(f"{source}: no such manifest or directory")


def is_url(log: str) -> bool:
    """True for object-store / remote URLs (``s3://``, ``gs://``, ``memory://``, chained
    ``simplecache::s3://``...); ``file://`` and plain paths are local."""
    scheme, sep, _ = log.partition("://")
    return (bool(sep) and scheme.lower() not in ("", "file")) or "::" in log


def compare_item(item: BatchItem) -> dict[str, Any]:
    """Compare one log (vehicle and camera topics); module-level for worker processes.

    A log given as a URL is fetched through fsspec into a temporary file first (workers of a
    cluster without a shared file system read the logs from an object store that way).
    """
    from uwval.comparison import compare_logs

    if is_url(item.log):
        import tempfile

        check_remote_allowed(item.log, item.allow, item.name)
        with tempfile.TemporaryDirectory(prefix="uwval-") as tmp:
            local = Path(tmp) / Path(item.log.split("://", 1)[1]).name
            _fetch(item.log, local)
            result = compare_logs(local, **item.options)
    else:
        result = compare_logs(item.log, **item.options)
    return {
        "name": item.name,
        "log": item.log,
        "factors": item.factors,
        "bridge": item.bridge,
        "comparison": result.to_json(),
    }


def _fetch(url: str, dest: Path) -> None:
    """Copy one remote file to ``dest`` with fsspec (installed with the dask extra)."""
    try:
        import fsspec
    except ImportError as exc:
        raise ConfigError(f"{url}: reading URLs needs fsspec (pip install 'uwval[dask]')") from exc
    try:
        with fsspec.open(url, "rb") as src, open(dest, "wb") as out:
            while chunk := src.read(1 << 22):
                out.write(chunk)
    except FileNotFoundError as exc:
        raise ConfigError(f"{url}: no such object") from exc


@dataclass
class BatchResult:
    """Per-run comparison JSON, the failures, and the tidy results table built from them."""

    runs: list[dict[str, Any]]
    failed: list[dict[str, Any]]
    table: Any  # uwval.results.ResultsTable

    def save(self, out_dir: Path) -> list[Path]:
        """Write comparisons.json and the results table (CSV, JSON, Parquet if available)."""
        comp = out_dir / "comparisons.json"
        try:
            out_dir.mkdir(parents=True, exist_ok=True)
            comp.write_text(json.dumps({"runs": self.runs, "failed": self.failed}, indent=1))
        except OSError as exc:
            raise ConfigError(f"{comp}: cannot write the results: {exc.strerror or exc}") from None
        written = [comp]
        written += list(self.table.save(out_dir))
        return written


def compare_batch(
    source: Path,
    *,
    executor: Executor | str = Executor.LOCAL,
    workers: int | None = None,
    scheduler: str | None = None,
    options: dict[str, Any] | None = None,
    progress: bool = True,
    allow_protocols: Collection[str] = (),
) -> BatchResult:
    """Compare every log of ``source``; gather the results into one table.

    ``allow_protocols``: remote protocols (``s3``, ``gs``, ``memory``...) whose URLs in the
    manifest may be fetched, besides those in ``UWVAL_ALLOW_PROTOCOLS``; others are refused.
    """
    from uwval.results import ResultsTable

    items = items_from(source, options, allow=allow_protocols)
    outcomes = run_tasks(
        compare_item,
        items,
        [i.name for i in items],
        executor=executor,
        workers=workers,
        scheduler=scheduler,
        progress=progress,
        description=f"compare {len(items)} logs",
    )
    runs = [o.value for o in outcomes if o.ok and o.value is not None]
    failed = [{"name": o.key, "error": o.error} for o in outcomes if not o.ok]
    table = ResultsTable.from_comparisons(
        [(r["name"], r["factors"], r["comparison"]) for r in runs]
    )
    return BatchResult(runs, failed, table)
