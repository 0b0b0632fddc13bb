"""Wall time of ``uwval demo`` as a user runs it (whole command, fresh process). Target (issue 30):
<= 30 s on an idle 2-core machine, the best of the runs (load only ever adds time)."""

from __future__ import annotations

import tempfile
from pathlib import Path

from benchmarks.common import BenchRow, median, python_cmd, run_command


def run(quick: bool = False) -> list[BenchRow]:
    walls, rss = [], []
    with tempfile.TemporaryDirectory() as tmp:
        for i in range(1 if quick else 2):
            wall, mem = run_command(
                python_cmd("-m", "uwval", "demo", "-o", str(Path(tmp) / f"demo{i}"))
            )
            walls.append(wall)
            rss.append(mem)
    w = min(walls)
    return [
        BenchRow(
            "uwval demo, whole command, best wall",
            w,
            "s",
            target="<= 30 s (idle 2-core)",
            met=w <= 30,
            notes=f"runs {', '.join(f'{x:.1f}' for x in walls)} s (median {median(walls):.1f}); "
            f"peak RSS of the parent {max(rss):.0f} MiB",
        )
    ]


if __name__ == "__main__":
    for row in run(quick=True):
        print(row.as_dict())
