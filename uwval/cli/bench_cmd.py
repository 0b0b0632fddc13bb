"""``uwval bench``: run the benchmarks of a uwval checkout's ``benchmarks/`` folder.

The benchmarks are not part of the wheel (they need evo and write large inputs), so the
command looks for a checkout: the current folder or one above it, or the checkout an editable
install points to. From a plain wheel outside a checkout it says so and exits 2.
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Annotated

import typer

from uwval.cli import app
from uwval.errors import ConfigError


def find_checkout(start: Path | None = None) -> Path | None:
    """The uwval checkout holding ``benchmarks/__main__.py``: ``start`` (default: the current
    folder) or a folder above it, else the checkout of an editable install; None if none."""
    import uwval

    here = (start or Path.cwd()).resolve()
    candidates = [here, *here.parents, Path(uwval.__file__).resolve().parent.parent]
    for root in candidates:
        if (root / "benchmarks" / "__main__.py").is_file() and (root / "pyproject.toml").is_file():
            return root
    return None


@app.command()
def bench(
    quick: Annotated[bool, typer.Option(help="Smaller inputs, fewer repetitions.")] = False,
    only: Annotated[list[str] | None, typer.Option(help="Areas to run (repeatable).")] = None,
) -> None:
    """Measure uwval against its peers (evo, rosbags, mcap_ros2) side by side.

    Needs a uwval checkout (the benchmarks are not installed with the wheel): run it inside one.
    """
    root = find_checkout()
    if root is None:
        raise ConfigError(
            "uwval bench runs the benchmarks/ folder of a uwval checkout, which an installed "
            "wheel does not contain: run it inside a checkout (pip install -e '.[bench]')"
        )
    sys.path.insert(0, str(root))
    from benchmarks.__main__ import main as bench_main

    argv = (["--quick"] if quick else []) + (["--only", *only] if only else [])
    raise typer.Exit(bench_main(argv))
