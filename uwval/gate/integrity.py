"""The gate's input checks: results that cannot say whether their logs were read whole are
refused (:class:`GateInputError`, exit 2), and the embedded defaults are found by name.

A compare result says what its log readers dropped and warned about in ``reference.dropped``
/ ``reference.warnings`` and ``other.dropped`` / ``other.warnings`` (per topic under
``topics`` too). A result without them (hand-made, trimmed, or written by an old tool) might
come from a log that was cut short: gating its numbers would pass what was never checked.
A results table (CSV/JSON/Parquet) carries the same facts as rows (axis ``reference`` /
``other``, metric ``n_warnings``); a table without those rows is refused the same way.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

from uwval.errors import ConfigError
from uwval.results import AXES, ResultsTable
from uwval.results.schema import SOURCES

#: What each source section of a compare result must say (what its reader dropped, warned).
INTEGRITY_FIELDS: tuple[str, ...] = ("dropped", "warnings")
#: Name of the embedded defaults (``--thresholds default``, ``--baseline default``).
DEFAULT_NAME = "default"


class GateInputError(ConfigError):
    """The gate's input cannot be trusted or found (missing integrity fields, no default)."""


def missing_integrity(comparison: Mapping[str, Any]) -> list[str]:
    """The integrity fields a compare JSON lacks, as dotted paths (empty: all present).

    Every result section is checked: the top level when it holds ``axes`` and each entry of
    ``topics``; each must have ``reference`` and ``other`` with ``dropped`` and ``warnings``.
    """
    sections: list[tuple[str, Mapping[str, Any]]] = []
    topics = comparison.get("topics")
    if isinstance(topics, Mapping):
        sections += [(f"topics.{k}.", v) for k, v in topics.items() if isinstance(v, Mapping)]
    if "axes" in comparison and not sections:
        sections.append(("", comparison))
    missing: list[str] = []
    for prefix, sect in sections:
        for src in SOURCES:
            info = sect.get(src)
            if not isinstance(info, Mapping):
                missing.append(f"{prefix}{src}")
                continue
            missing += [f"{prefix}{src}.{k}" for k in INTEGRITY_FIELDS if k not in info]
    return missing


def _table_gaps(table: ResultsTable) -> list[str]:
    """(run/topic) pairs of a table with pose rows but no reader-warning rows per source."""
    df = table.df
    pose = df[df["axis"].isin(AXES)][["run", "topic"]].drop_duplicates()
    warn = df[df["axis"].isin(SOURCES) & (df["metric"] == "n_warnings")]
    have = set(zip(warn["run"], warn["topic"], warn["axis"], strict=True))
    gaps = []
    for run, topic in zip(pose["run"], pose["topic"], strict=True):
        lacking = [s for s in SOURCES if (run, topic, s) not in have]
        if lacking:
            gaps.append(f"{run}/{topic} ({' and '.join(f'{s}.n_warnings' for s in lacking)})")
    return gaps


def require_integrity(
    table: ResultsTable,
    comparisons: Iterable[tuple[str, Mapping[str, Any] | None]],
    source: str | Path,
) -> None:
    """Refuse results whose runs cannot say whether their logs were read whole.

    ``comparisons``: (run name, compare JSON or None) per run; a run with its JSON is checked
    on the JSON (every section's ``dropped`` and ``warnings``), the others on the table's
    ``n_warnings`` rows. ``source`` names the file in the message.
    """
    bad: list[str] = []
    for run, comp in comparisons:
        if comp is None:
            continue
        gaps = missing_integrity(comp)
        if gaps:
            bad.append(f"run {run} lacks {', '.join(gaps[:4])}" + (" ..." if len(gaps) > 4 else ""))
    with_json = {run for run, comp in comparisons if comp is not None}
    rest = ResultsTable.from_dataframe(
        table.df[~table.df["run"].isin(with_json)], table.factors, table.meta
    )
    gaps = _table_gaps(rest)
    if gaps:
        bad.append(
            "no reader-warning rows for " + ", ".join(gaps[:3]) + (" ..." if len(gaps) > 3 else "")
        )
    if bad:
        raise GateInputError(
            f"{display_path(source)}: refused: {bad[0]}"
            + (f" (and {len(bad) - 1} more run(s))" if len(bad) > 1 else "")
            + ": without what its log readers dropped and warned about, the results cannot "
            "say whether their logs were read whole; compare the logs again with this uwval"
        )


def embedded(kind: str, name: str) -> Path | None:
    """The embedded default file for ``--thresholds default`` / ``--baseline default``
    (``kind``: ``thresholds`` or ``baselines``), or None when ``name`` is not ``default``."""
    if name != DEFAULT_NAME:
        return None
    from uwval.resources import data_path

    suffix = ".toml" if kind == "thresholds" else ".json"
    try:
        return data_path(kind, DEFAULT_NAME + suffix)
    except ConfigError as exc:
        raise GateInputError(f"--{kind.rstrip('s')} default: {exc}") from None


def resolve_input(kind: str, value: str | Path | None) -> Path | None:
    """A thresholds/baseline argument as a path: ``default`` is the embedded file."""
    if value is None:
        return None
    found = embedded(kind, str(value))
    return found if found is not None else Path(value)


def display_path(path: str | Path) -> str:
    """A path as the report and the messages show it: an embedded default as
    ``default (embedded: thresholds/default.toml)`` (never a site-packages path)."""
    text = str(path)
    try:
        from uwval.resources import data_dir

        root = data_dir().resolve()
        rel = Path(text).resolve().relative_to(root)
    except (ConfigError, ValueError, OSError):
        return text
    return f"default (embedded: {rel.as_posix()})"


def names_of(runs: Sequence[Any]) -> list[tuple[str, Mapping[str, Any] | None]]:
    """(name, comparison) of :class:`uwval.results.RunRecord` objects, for
    :func:`require_integrity`."""
    return [(str(r.name), r.comparison) for r in runs]
