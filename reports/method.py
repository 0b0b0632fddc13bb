"""The one line that says how the numbers were made: time sync, clock offset, alignment and
the frame the errors are computed in. The report prints it under its title, at the foot of
every PDF page and in ``uwval compare --html``'s page, so no figure is read without it."""

from __future__ import annotations

from collections import Counter
from collections.abc import Iterable, Mapping
from typing import Any

from uwval.reports.numbers import Quantity, fmt_unit

_SYNC_WORDS = {
    "interp": "interp (Unity interpolated onto the Gazebo stamps)",
    "nearest": "nearest stamp",
}


def _sync(comp: Mapping[str, Any]) -> str:
    sync = comp.get("sync") or {}
    method = str(sync.get("method") or "?")
    text = _SYNC_WORDS.get(method, method)
    if method == "nearest" and sync.get("max_diff_s") is not None:
        text += f" (max dt {fmt_unit(sync.get('max_diff_s'), Quantity.DURATION)})"
    return text


def _offset(comp: Mapping[str, Any]) -> str:
    off = comp.get("offset") or {}
    applied = fmt_unit(off.get("applied_s") or 0.0, Quantity.DURATION)
    source = str(off.get("source") or "")
    drift = off.get("drift_ppm")
    text = f"{applied} ({source})" if source else applied
    if isinstance(drift, (int, float)):
        text += f", drift {drift:.1f} ppm removed"
    return text


def _alignment(comp: Mapping[str, Any]) -> str:
    return str((comp.get("alignment") or {}).get("mode") or "none")


def _frame(comp: Mapping[str, Any]) -> str:
    frame = comp.get("frame") or {}
    shown = str(frame.get("compared_in") or "?").upper()
    other = frame.get("configured")
    return f"{shown} (Unity side read as {other})" if other else shown


def _summarise(values: list[str]) -> str:
    """One value, or each distinct value with how many runs used it."""
    counts = Counter(values)
    if len(counts) == 1:
        return values[0]
    return "; ".join(f"{v} in {n} run(s)" for v, n in counts.most_common())


def method_line(comparisons: Iterable[Mapping[str, Any] | None], options: Mapping[str, Any]) -> str:
    """ "sync ...; clock offset ...; alignment ...; errors in ..." over every run's compare
    JSON; from the compare options when no JSON is at hand (a bare results table)."""
    comps = [c for c in comparisons if c]
    if comps:
        return (
            f"Method: sync {_summarise([_sync(c) for c in comps])}; "
            f"clock offset {_summarise([_offset(c) for c in comps])}; "
            f"alignment {_summarise([_alignment(c) for c in comps])}; "
            f"errors in {_summarise([_frame(c) for c in comps])}."
        )
    if options:
        given = ", ".join(f"{k} {v}" for k, v in options.items() if k != "path_b")
        return f"Method: compare options {given} (the results do not record their method)."
    return (
        "Method: not recorded in these results (a results table without the compare "
        "JSON); see how they were made."
    )
