"""``uwval inspect LOG``: what a log holds (topics, types, counts, rates, span, largest gaps)."""

from __future__ import annotations

import json
import sys
import warnings
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Annotated, Any

import numpy as np
import typer
from rich.markup import escape
from rich.table import Table

from uwval.cli import app
from uwval.cli.console import output_console
from uwval.cli.shared_options import JSON, RESULT_FILE


@dataclass
class TopicSummary:
    """One topic of an inspected log; times in seconds (log / receive time)."""

    name: str
    type: str
    count: int
    start: float | None
    end: float | None
    duration: float
    rate_hz: float | None
    largest_gaps: list[dict[str, float]] = field(default_factory=list)  # {"at": s, "gap": s}


@dataclass
class LogSummary:
    """The whole log: path, span, topics, and warnings (e.g. bytes lost to truncation)."""

    path: str
    start: float | None
    end: float | None
    duration: float
    topics: list[TopicSummary]
    warnings: list[str]


def summarize(path: Path, n_gaps: int = 3) -> LogSummary:
    """Summarise a log (ROS formats by log time; CSV/TUM by their stamps)."""
    from uwval.io.formats import TEXT_KINDS, log_kind
    from uwval.io.reader import read_stream, topic_times

    notes: list[str] = []
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        if log_kind(path) in TEXT_KINDS:
            s = read_stream(path, "")
            infos_types = [(s.topic or path.stem, "text/" + log_kind(path))]
            times = {infos_types[0][0]: s.t}
        else:
            infos, times = topic_times(path)
            infos_types = [(i.name, i.type) for i in infos]
        notes.extend(str(w.message) for w in caught)
    topics = []
    for name, typ in infos_types:
        t = times.get(name, np.zeros(0, dtype=np.int64))
        topics.append(_topic(name, typ, t, n_gaps))
    starts = [x.start for x in topics if x.start is not None]
    ends = [x.end for x in topics if x.end is not None]
    start = min(starts) if starts else None
    end = max(ends) if ends else None
    dur = (end - start) if start is not None and end is not None else 0.0
    return LogSummary(str(path), start, end, dur, topics, notes)


def _topic(name: str, typ: str, t: np.ndarray, n_gaps: int) -> TopicSummary:
    n = int(t.shape[0])
    if n == 0:
        return TopicSummary(name, typ, 0, None, None, 0.0, None)
    t = np.sort(t)
    start, end = float(t[0]) * 1e-9, float(t[-1]) * 1e-9
    dur = float(t[-1] - t[0]) * 1e-9
    rate = (n - 1) / dur if n > 1 and dur > 0 else None
    gaps = []
    if n > 1:
        d = np.diff(t)
        top = np.argsort(d)[::-1][:n_gaps]
        gaps = [{"at": float(t[i]) * 1e-9, "gap": float(d[i]) * 1e-9} for i in top]
    return TopicSummary(name, typ, n, start, end, dur, rate, gaps)


@app.command("inspect")
def inspect_cmd(
    log: Annotated[
        Path, typer.Argument(help="Log file (.mcap, .bag, .db3, .csv, .txt) or rosbag2 directory")
    ],
    as_json: Annotated[bool, typer.Option(*JSON.flags, help=JSON.help)] = False,
    gaps: Annotated[int, typer.Option(help="Largest gaps to list per topic", min=0)] = 3,
    output: Annotated[Path | None, typer.Option(*RESULT_FILE.flags, help=RESULT_FILE.help)] = None,
) -> None:
    """Show a log's topics, types, message counts, rates, time span and largest gaps, and
    the TF children compare can take as TOPIC#CHILD (with their chains through /tf_static)."""
    summary = summarize(log, gaps)
    tf = _tf_pairs(log, summary)
    chains = _tf_chains(log, summary)
    doc = asdict(summary)
    doc["tf_pairs"] = {
        name: [{"parent": a, "child": b, "count": n} for a, b, n in pairs]
        for name, pairs in tf.items()
    }
    doc["tf_chains"] = {
        name: [{"child": c, "chain": list(chain), "static_links": k} for c, chain, k in rows]
        for name, rows in chains.items()
    }
    if output is not None:
        from uwval.cli.compare_files import write_output

        write_output(output, json.dumps(doc, indent=2) + "\n", "the JSON result")
    if as_json:
        sys.stdout.write(json.dumps(doc, indent=2) + "\n")
        return
    _print_summary(summary, tf, chains)


def _print_summary(
    summary: LogSummary,
    tf: dict[str, list[tuple[str, str, int]]],
    chains: dict[str, list[tuple[str, tuple[str, ...], int]]],
) -> None:
    """The table of topics, then the TF pairs and chains, then the warnings."""
    console = output_console()
    table = Table(title=f"{summary.path}  span {summary.duration:.3f} s")
    for col in ("topic", "type", "count", "rate [Hz]", "start [s]", "end [s]", "largest gap [s]"):
        table.add_column(
            col,
            justify="right" if col not in ("topic", "type") else "left",
            no_wrap=col in ("topic", "type"),
        )
    for t in summary.topics:
        gap = (
            f"{t.largest_gaps[0]['gap']:.4f} @ {t.largest_gaps[0]['at']:.3f}"
            if t.largest_gaps
            else "-"
        )
        table.add_row(
            t.name,
            t.type,
            str(t.count),
            _fmt(t.rate_hz, ".2f"),
            _fmt(t.start, ".3f"),
            _fmt(t.end, ".3f"),
            gap,
        )
    console.print(table)
    for name, pairs in tf.items():  # compare takes one of them as TOPIC#CHILD
        listed = ", ".join(f"{a}->{b} ({n})" for a, b, n in pairs) or "none"
        console.print(f"{name} parent->child: {listed}", highlight=False, markup=False)
    for name, rows in chains.items():
        for child, chain, static_links in rows:
            if static_links:  # '=>' marks a static link (from /tf_static)
                path = " => ".join(chain[1:])
                console.print(
                    f"{name}#{child}: {chain[0]} -> {path} "
                    f"({static_links} static link(s) from /tf_static)",
                    highlight=False,
                    markup=False,
                )
    for note in summary.warnings:
        console.print(f"[yellow]warning:[/] {escape(note)}", highlight=False)


def _tf_pairs(log: Path, summary: LogSummary) -> dict[str, list[tuple[str, str, int]]]:
    """parent->child pairs (with counts) of every TFMessage topic of the log."""
    from uwval.io.decode import TF_TYPES
    from uwval.io.reader import tf_pairs

    with warnings.catch_warnings():  # what the log's reader warns about is in summary.warnings
        warnings.simplefilter("ignore")
        return {
            t.name: tf_pairs(log, t.name) for t in summary.topics if t.type in TF_TYPES and t.count
        }


def _tf_chains(log: Path, summary: LogSummary) -> dict[str, list[tuple[str, tuple[str, ...], int]]]:
    """The children TOPIC#CHILD reaches on each dynamic TF topic, through /tf_static."""
    from uwval.io.decode import TF_TYPES
    from uwval.io.reader import tf_chains

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return {
            t.name: tf_chains(log, t.name)
            for t in summary.topics
            if t.type in TF_TYPES and t.count and t.name != "/tf_static"
        }


def _fmt(x: Any, spec: str) -> str:
    return "-" if x is None else format(x, spec)
