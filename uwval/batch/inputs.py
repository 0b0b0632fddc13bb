"""What a batch compare reads: a manifest.json, a directory holding one, or a directory of logs.

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
