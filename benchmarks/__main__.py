"""``python -m benchmarks [--quick] [--only NAME ...] [--json FILE]``: every benchmark, one table.

Each ``benchmarks/bench_<area>.py`` exposes ``run(quick: bool) -> list[BenchRow]``: uwval and its
peer on the same input in the same process run, alternating repetitions, medians and ratio.
"""

from __future__ import annotations

import argparse
import importlib
import json
import platform
import sys
import traceback
from pathlib import Path

from benchmarks.common import BenchRow

AREAS = ("shapes", "compare", "decode", "sim", "bridge", "sweep", "reports", "demo")


def _machine() -> str:
    import os

    cpu = platform.processor() or platform.machine()
    return (
        f"{platform.system()} {platform.machine()} ({cpu}), {os.cpu_count()} cores, "
        f"Python {platform.python_version()}"
    )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks", description=__doc__)
    parser.add_argument("--quick", action="store_true", help="smaller inputs, fewer repetitions")
    parser.add_argument("--only", nargs="*", default=None, help=f"areas: {', '.join(AREAS)}")
    parser.add_argument("--json", type=Path, default=None, help="write the rows as JSON here")
    parser.add_argument(
        "--markdown",
        type=Path,
        default=None,
        help="write the table as Markdown here (for benchmarks/README.md)",
    )
    args = parser.parse_args(argv)
    rows: list[BenchRow] = []
    failures = []
    for area in args.only or AREAS:
        try:
            mod = importlib.import_module(f"benchmarks.bench_{area}")
        except ModuleNotFoundError as exc:
            print(f"[{area}] no benchmark module ({exc})", file=sys.stderr)
            continue
        print(f"[{area}] running...", file=sys.stderr, flush=True)
        try:
            rows.extend(mod.run(quick=args.quick))
        except Exception:
            failures.append(area)
            traceback.print_exc()
    _print(rows)
    if args.markdown:
        args.markdown.write_text(markdown_table(rows))
    if args.json:
        args.json.write_text(
            json.dumps({"machine": _machine(), "rows": [r.as_dict() for r in rows]}, indent=1)
        )
    return 1 if failures else 0


def markdown_table(rows: list[BenchRow]) -> str:
    """The rows as a Markdown table, headed by the date and the machine."""
    import datetime

    when = datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    lines = [
        f"Measured {when} on {_machine()}.",
        "",
        "| benchmark | uwval | peer | ratio | target | met | notes |",
        "| --- | ---: | ---: | ---: | --- | --- | --- |",
    ]
    for r in rows:
        peer = "" if r.peer is None else f"{r.peer:.4g} {r.unit} ({r.peer_name})"
        ratio = "" if r.ratio is None else f"{r.ratio:.1f}x"
        met = "" if r.met is None else ("yes" if r.met else "**no**")
        lines.append(
            f"| {r.name} | {r.uwval:.4g} {r.unit} | {peer} | {ratio} | {r.target} "
            f"| {met} | {r.notes} |"
        )
    return "\n".join(lines) + "\n"


def _print(rows: list[BenchRow]) -> None:
    from rich.console import Console
    from rich.table import Table

    table = Table(title=f"uwval benchmarks — {_machine()}")
    for col in ("benchmark", "uwval", "peer", "ratio", "target", "met"):
        table.add_column(col, justify="left" if col in ("benchmark", "target") else "right")
    for r in rows:
        peer = "" if r.peer is None else f"{r.peer:.4g} {r.unit} ({r.peer_name})"
        ratio = "" if r.ratio is None else f"{r.ratio:.1f}x"
        met = "" if r.met is None else ("yes" if r.met else "NO")
        table.add_row(r.name, f"{r.uwval:.4g} {r.unit}", peer, ratio, r.target, met)
    Console().print(table)


if __name__ == "__main__":
    raise SystemExit(main())
