"""``uwval bench``: run the benchmarks of the checkout's ``benchmarks/`` folder."""

from __future__ import annotations

import sys
from typing import Annotated

import typer

from uwval.cli import app
from uwval.errors import ConfigError
from uwval.resources import DATA_DIR


@app.command()
def bench(
    quick: Annotated[bool, typer.Option(help="Smaller inputs, fewer repetitions.")] = False,
    only: Annotated[list[str] | None, typer.Option(help="Areas to run (repeatable).")] = None,
) -> None:
    """Measure uwval against its peers (evo, rosbags, mcap_ros2) side by side."""
    root = DATA_DIR.parent
    if not (root / "benchmarks" / "__main__.py").exists():
        raise ConfigError(f"{root}/benchmarks not found: run from a uwval checkout")
    sys.path.insert(0, str(root))
    from benchmarks.__main__ import main as bench_main

    argv = (["--quick"] if quick else []) + (["--only", *only] if only else [])
    raise typer.Exit(bench_main(argv))
