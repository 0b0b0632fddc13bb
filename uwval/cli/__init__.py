"""The ``uwval`` command line: a thin typer layer over functions that return result objects.

Each area registers its commands from its own module (``compare_cmd``, ``io_cmd``, ...), so
the areas do not edit one file. ``main`` turns every :class:`UwvalError` into a one-line
message and exit code 2 (no traceback reaches the user).
"""

from __future__ import annotations

import importlib
import sys

import typer
from rich.console import Console

from uwval.errors import UwvalError

app = typer.Typer(
    name="uwval",
    help="Validate that an underwater vehicle's pose in Unity matches Gazebo's.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)

err_console = Console(stderr=True)

#: Modules that register commands on ``app`` when imported (missing ones are skipped).
COMMAND_MODULES = (
    "uwval.cli.compare_cmd",
    "uwval.cli.io_cmd",
    "uwval.cli.simulate_cmd",
    "uwval.cli.bridge_cmd",
    "uwval.cli.report_cmd",
    "uwval.cli.demo_cmd",
    "uwval.cli.teleop_cmd",
    "uwval.cli.bench_cmd",
)


@app.callback()
def _root() -> None:
    """uwval: simulate, bridge, record, compare, report and gate Gazebo/Unity pose logs."""


def _register() -> None:
    for name in COMMAND_MODULES:
        try:
            importlib.import_module(name)
        except ModuleNotFoundError as exc:
            if exc.name != name:  # a real missing dependency inside the module
                raise


def main(argv: list[str] | None = None) -> None:
    """Console entry point: run the app, printing UwvalErrors as clean messages."""
    _register()
    try:
        app(args=argv, standalone_mode=True)
    except UwvalError as exc:
        err_console.print(f"[bold red]error:[/] {exc}", highlight=False, soft_wrap=True)
        sys.exit(2)
    except KeyboardInterrupt:
        err_console.print("[yellow]interrupted[/]")
        sys.exit(130)
