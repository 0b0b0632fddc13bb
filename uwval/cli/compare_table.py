"""The table ``uwval compare`` prints per topic pair, with rich.

On a terminal the table is short (it fits 80 columns: the rest is in ``--json``); into a
file or a pipe it has every column and ten significant digits, and nothing is wrapped.
"""

from __future__ import annotations

from typing import Any

from rich import box
from rich.console import Console
from rich.markup import escape
from rich.table import Table

from uwval.comparison.logs import APE_STATISTICS, LogComparison


def _fmt(v: Any, digits: int = 4) -> str:
    """A number for a terminal: 4 significant digits, small values as 5.03e-04."""
    if v is None:
        return "-"
    if isinstance(v, float):
        if v != 0 and abs(v) < 1e-3:
            return f"{v:.{digits - 1}e}"
        return f"{v:.{digits}g}"
    return str(v)


def _fmt_full(v: Any, digits: int = 10) -> str:
    """A number for a file or a pipe: 10 significant digits (``digits`` is never fewer)."""
    if v is None:
        return "-"
    return f"{v:.{max(digits, 10)}g}" if isinstance(v, float) else str(v)


def sync_title(doc: dict[str, Any]) -> str:
    """How the samples were associated, as the table's title says it."""
    sync = doc.get("sync") or {}
    if sync.get("method") == "nearest":
        return f"sync nearest, max diff {sync.get('max_diff_s', 0.01):g} s, as evo"
    return f"sync {sync.get('method')}: Unity side interpolated at the reference stamps"


def _rows(doc: dict[str, Any], full: bool) -> tuple[list[str], list[list[str]]]:
    """Column names and one row per axis (x y z m, roll pitch yaw deg)."""
    cols = ["axis", "MAE", "RMSE", "max", "bias", "Pearson r"]
    if full:  # fits no 80-column terminal: only where nothing wraps
        cols += ["p95", "median", "std", "Pearson 95% CI", "Pearson p", "n"]
    num = _fmt_full if full else _fmt
    rows = []
    for ax, s in doc["axes"].items():
        r = s.get("pearson_r")
        r_text = "n/a" if r is None else (_fmt_full(r) if full else f"{r:.6f}")
        unit = s.get("unit", "")
        row = [
            f"{ax} [{unit}]" if unit else ax,
            num(s["mae"]),
            num(s["rmse"]),
            num(s["max"]),
            num(s["bias"]),
            r_text,
        ]
        if full:
            ci = s.get("pearson_ci")
            row += [
                num(s.get("p95")),
                num(s.get("median")),
                num(s.get("std")),
                "n/a" if not ci or None in ci else f"[{_fmt_full(ci[0])}, {_fmt_full(ci[1])}]",
                num(s.get("pearson_p")),
                str(s.get("pearson_n", "")),
            ]
        rows.append(row)
    return cols, rows


def _lines(doc: dict[str, Any], full: bool) -> list[str]:
    """The plain-text lines under the table: samples, norms, APE, offset and latency."""
    num = _fmt_full if full else _fmt
    lines = []
    undefined = [ax for ax, s in doc["axes"].items() if s.get("pearson_r") is None]
    if undefined:
        reasons = {doc["axes"][ax].get("pearson_reason") or "undefined" for ax in undefined}
        lines.append(f"Pearson r n/a for {', '.join(undefined)}: {'; '.join(sorted(reasons))}")
    pn, rot, counts = doc["position_error_norm"], doc["rotation_error_deg"], doc["counts"]
    lines.append(
        f"samples {doc['n_samples']} (matched {counts['matched']}, masked {counts['masked']}, "
        f"dropped {counts['dropped']}); sync {doc['sync']['method']}; frame "
        f"{doc['frame']['configured']}; align {doc['alignment']['mode']}"
    )
    lines.append(
        f"position error norm [m]: rmse {num(pn['rmse'])} mean {num(pn['mean'])} "
        f"median {num(pn['median'])} max {num(pn['max'])}; rotation [deg]: rmse "
        f"{num(rot['rmse'])} max {num(rot['max'])}"
    )
    ape = doc.get("ape")
    if ape:  # -r/--pose_relation: evo_ape's statistics, all digits (as evo prints them)
        lines.append(
            f"APE w.r.t. {ape['pose_relation']} [{ape['unit']}]: "
            + " ".join(f"{k} {ape[k]:.9g}" for k in APE_STATISTICS)
        )
    off = doc["offset"]
    line = f"clock offset {num(off['applied_s'], 6)} s"
    if off.get("estimate"):
        line += f" (estimated, +/- {num(off['estimate']['uncertainty_s'], 3)} s)"
    if doc.get("latency"):
        lat = doc["latency"]
        line += f"; latency {num(lat['mean_ms'])} ms mean, {num(lat['p95_ms'])} ms p95"
    if off.get("drift_ppm"):
        line += f"; clock drift {off['drift_ppm']:+.2f} ppm removed"
    lines.append(line)
    if doc.get("lag"):  # the study's answer in a sentence (uwval.comparison.lag)
        lines.append(doc["lag"]["sentence"])
    return lines


def print_topic(console: Console, doc: dict[str, Any], title: str) -> None:
    """One topic pair's table and lines; its warnings go after them as ``warning:`` lines."""
    full = not console.is_terminal  # a file or a pipe: every column, every digit
    cols, rows = _rows(doc, full)
    table = Table(
        title=escape(f"{title}  ({sync_title(doc)})"),
        title_justify="left",
        box=box.SIMPLE_HEAD,
        pad_edge=False,
    )
    for col in cols:
        table.add_column(col, justify="left" if col == "axis" else "right", no_wrap=True)
    for row in rows:
        table.add_row(escape(row[0]), *row[1:])
    console.print(table)
    for line in _lines(doc, full):
        console.print(line, markup=False, highlight=False)
    for w in doc.get("warnings", []):
        console.print(f"[yellow]warning:[/] {escape(w)}", highlight=False)


def print_comparison(console: Console, result: LogComparison) -> None:
    """Every topic pair of ``result``: a table each."""
    for name, res in result.results.items():
        title = f"{name}: {res.other.describe()} vs {res.reference.describe()}"
        print_topic(console, result.topic_json(name), title)
