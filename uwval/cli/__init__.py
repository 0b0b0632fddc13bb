"""The ``uwval`` command line: a thin typer layer over functions that return result objects.

Each area registers its commands from its own module (``compare_cmd``, ``io_cmd``, ...), so
the areas do not edit one file. ``main`` turns every :class:`UwvalError`, and output that
cannot be written (stdout on a full device), into a one-line message and exit code 2 (no
traceback reaches the user).

typer is the only command-line parser; rich prints the tables (:mod:`uwval.cli.console`:
results on stdout, never wrapped when piped; errors on stderr). ``uwval.cli.app`` is created
on first use, and only the module of the command typed is imported.
"""

from __future__ import annotations

import contextlib
import errno
import importlib
import os
import sys
from typing import TYPE_CHECKING, Any

from uwval.errors import UwvalError

if TYPE_CHECKING:
    import typer

#: One BLAS thread for the command line, unless the user set it: uwval's arrays are long
#: vectors and 3x3 matrices, where OpenBLAS's worker threads cost more than they give. On a
#: 2-core machine a 36,000-element ``np.dot`` took 4-16 ms with its threads woken for every
#: call, against 5 us on one; a compare made dozens of such calls. Set before numpy loads
#: (``import uwval`` and this module do not load it); subprocesses inherit it.
BLAS_THREADS = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")
for _var in BLAS_THREADS:
    os.environ.setdefault(_var, "1")

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
    "uwval.cli.rpe_cmd",
)

#: Which module defines each top-level command, so that ``uwval compare`` imports only the
#: compare module (start-up time is part of the whole-command cost of small jobs).
COMMAND_HOME = {
    "compare": "uwval.cli.compare_cmd",
    "doctor": "uwval.cli.compare_cmd",
    "inspect": "uwval.cli.io_cmd",
    "simulate": "uwval.cli.simulate_cmd",
    "bridge": "uwval.cli.bridge_cmd",
    "report": "uwval.cli.report_cmd",
    "check": "uwval.cli.report_cmd",
    "demo": "uwval.cli.demo_cmd",
    "teleop": "uwval.cli.teleop_cmd",
    "bench": "uwval.cli.bench_cmd",
    "rpe": "uwval.cli.rpe_cmd",
}

_app: typer.Typer | None = None


def embedded_defaults() -> dict[str, list[str]]:
    """The embedded defaults this installation carries, by kind (experiments, thresholds,
    baselines, vehicles): the names that ``simulate NAME``, ``--thresholds NAME`` and
    ``--baseline NAME`` accept."""
    from uwval.resources import data_dir

    root = data_dir()
    kinds = ("experiments", "thresholds", "baselines", "vehicles")
    return {
        kind: sorted(p.stem for p in (root / kind).iterdir() if p.suffix in (".toml", ".json"))
        for kind in kinds
        if (root / kind).is_dir()
    }


def version_text() -> str:
    """What ``uwval --version`` prints: the version, then the embedded defaults by name."""
    from uwval import __version__

    lines = [f"uwval {__version__}"]
    for kind, names in embedded_defaults().items():
        lines.append(f"embedded {kind}: {', '.join(names) or '(none)'}")
    return "\n".join(lines)


def _root_callback(typer: Any) -> Any:
    """The app's root callback, with ``--version`` (built here: typer is imported lazily)."""

    def show_version(value: bool) -> None:
        if value:
            print(version_text())
            raise typer.Exit()

    def root(
        version: bool = typer.Option(
            False,
            "--version",
            help="Print uwval's version and the embedded defaults it carries, and exit.",
            callback=show_version,
            is_eager=True,
        ),
    ) -> None:
        """uwval: simulate, bridge, record, compare, report and gate Gazebo/Unity pose logs."""

    return root


def get_app() -> typer.Typer:
    """The typer application (created on first use)."""
    global _app
    if _app is None:
        import typer

        _app = typer.Typer(
            name="uwval",
            help="Validate that an underwater vehicle's pose in Unity matches Gazebo's.",
            no_args_is_help=True,
            add_completion=False,
            pretty_exceptions_enable=False,
            context_settings={"help_option_names": ["-h", "--help"]},
        )
        _app.callback()(_root_callback(typer))
    return _app


def __getattr__(name: str) -> Any:
    """``from uwval.cli import app`` creates the typer app on first use."""
    if name == "app":
        return get_app()
    raise AttributeError(f"module 'uwval.cli' has no attribute {name!r}")


def _register(argv: list[str] | None = None) -> None:
    """Import the command modules: only the one needed when ``argv`` names a known command."""
    first = next((a for a in (argv or []) if not a.startswith("-")), None)
    if first in COMMAND_HOME:
        importlib.import_module(COMMAND_HOME[first])
        return
    for name in COMMAND_MODULES:
        try:
            importlib.import_module(name)
        except ModuleNotFoundError as exc:
            if exc.name != name:  # a real missing dependency inside the module
                raise


def _print_error(prefix_markup: str, text: str) -> None:
    """One line on stderr: a coloured prefix, then ``text`` verbatim (never as markup)."""
    from rich.markup import escape

    from uwval.cli.console import error_console

    # stderr unwritable too: the exit status still tells
    with contextlib.suppress(OSError, ValueError):
        error_console().print(f"{prefix_markup} {escape(text)}", highlight=False, soft_wrap=True)


#: errno values of a failed write to stdout that are the environment's, not uwval's:
#: a full device (``> /dev/full``), a reader that went away (``| head``), an I/O error.
_OUTPUT_ERRNOS = frozenset({errno.ENOSPC, errno.EPIPE, errno.EIO, errno.EFBIG, errno.EDQUOT})


def _silence_stdout() -> None:
    """Point fd 1 at /dev/null, so that the interpreter's final flush of what is still
    buffered cannot fail a second time (and print "Exception ignored ...")."""
    import os

    with contextlib.suppress(OSError, ValueError):
        if sys.stdout is not None:
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())


def _flush_output() -> None:
    """Flush stdout and stderr (None when the process started with that fd closed)."""
    for stream in (sys.stdout, sys.stderr):
        if stream is not None:
            stream.flush()


def _dispatch(args: list[str], argv: list[str] | None) -> None:
    """Run one command through typer (the only parser)."""
    _register(args)
    try:
        get_app()(args=argv, standalone_mode=True)
    except SystemExit:
        _flush_output()
        raise
    _flush_output()  # a failed write surfaces here, inside main's handlers


def main(argv: list[str] | None = None) -> None:
    """Console entry point: run the app, printing UwvalErrors as clean messages.

    Exit status 2 with one line on stderr for a :class:`UwvalError` and for output that
    cannot be written (stdout on a full device); 130 on Ctrl-C.
    """
    args = sys.argv[1:] if argv is None else argv
    if not sys.stdout.isatty():
        # typer's help is printed by rich, which wraps at 80 columns when stdout is a file or a
        # pipe; scripts grep it whole (our own tables never wrap: uwval.cli.console)
        os.environ.setdefault("COLUMNS", "200")
    try:
        _dispatch(args, argv)
    except UwvalError as exc:
        _print_error("[bold red]error:[/]", str(exc))
        sys.exit(2)
    except KeyboardInterrupt:
        _print_error("[yellow]interrupted[/]", "")
        sys.exit(130)
    except OSError as exc:
        if exc.errno not in _OUTPUT_ERRNOS or exc.filename is not None:
            raise  # not a failed write to stdout: a bug, keep its traceback
        _silence_stdout()
        if exc.errno == errno.EPIPE:  # the reader went away (| head): nothing to tell it
            sys.exit(1)
        _print_error("[bold red]error:[/]", f"cannot write the output: {exc.strerror or exc}")
        sys.exit(2)
