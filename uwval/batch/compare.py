"""Batch compare: every log of an experiment directory (or manifest) into one results table.

A task is one whole log, so a batch runs on any executor of :mod:`uwval.batch.executors`
(process pool or Dask distributed) and gives the same table either way. A log that fails to
compare is reported with its run name and cause while the others complete. What a batch
reads (manifests, directories of logs, allowed remote protocols) is :mod:`uwval.batch.inputs`.
"""

from __future__ import annotations

import json
from collections.abc import Collection
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from uwval.batch.executors import Executor, run_tasks
from uwval.batch.inputs import BatchItem, check_remote_allowed, is_url, items_from
from uwval.errors import ConfigError


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
