"""The consoles every command prints through: results on stdout, messages on stderr.

On a terminal rich wraps to the window; into a file, a pipe or a CI log nothing is wrapped
or cut (rich would otherwise assume 80 columns), so that ``grep`` and scripts see whole
lines and every column of a table.
"""

from __future__ import annotations

import sys
from typing import Any, TextIO

from rich.console import Console

#: The width given to a console that is not a terminal: wider than any line uwval prints.
UNWRAPPED_WIDTH = 100_000


def output_console(*, file: TextIO | None = None, record: bool = False) -> Console:
    """A rich Console for results (stdout unless ``file``): the terminal's width on a
    terminal, no wrapping anywhere else. ``record`` keeps the text for ``export_text``."""
    target = file if file is not None else sys.stdout
    if file is None and target is not None and target.isatty():
        return Console(record=record)
    return Console(
        file=file, width=UNWRAPPED_WIDTH, soft_wrap=True, record=record, force_terminal=False
    )


def error_console() -> Console:
    """A rich Console for warnings and errors (stderr), never wrapped when not a terminal."""
    if sys.stderr is not None and sys.stderr.isatty():
        return Console(stderr=True)
    return Console(stderr=True, width=UNWRAPPED_WIDTH, soft_wrap=True)


def warn(text: str, console: Any = None) -> None:
    """One ``warning:`` line on stderr, the text printed verbatim (never read as markup)."""
    from rich.markup import escape

    (console or error_console()).print(
        f"[yellow]warning:[/] {escape(text)}", highlight=False, soft_wrap=True
    )
