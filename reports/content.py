"""The report's content, independent of the output format: sections of text, tables, figures.

:mod:`uwval.reports.builder` fills a :class:`Report`; :mod:`uwval.reports.html` and
:mod:`uwval.reports.pdf` render the same object, so the HTML page and the PDF say the same thing.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, Literal

from matplotlib.figure import Figure


@dataclass
class Text:
    """A paragraph (``p``), a preformatted block (``pre``) or a bullet list (``list``)."""

    text: str | Sequence[str]
    kind: Literal["p", "pre", "list"] = "p"
    css: str = ""  # extra class, e.g. "pass" / "fail" for the verdict line

    block: str = "text"


@dataclass
class Table:
    """A table of already formatted cells; ``flags`` marks cells (e.g. "bad") for styling."""

    title: str
    columns: list[str]
    rows: list[list[str]]
    caption: str = ""
    flags: dict[tuple[int, int], str] = field(default_factory=dict)

    block: str = "table"

    def flag(self, r: int, c: int) -> str:
        return self.flags.get((r, c), "")


@dataclass
class Plot:
    """A matplotlib figure with a caption; rendered to PNG (HTML) and vector (PDF)."""

    title: str
    figure: Figure
    caption: str = ""
    png_base64: str = ""  # filled by the HTML renderer

    block: str = "plot"


Block = Text | Table | Plot


@dataclass
class Section:
    """A titled part of the report; ``collapsed`` sections render as closed <details>."""

    id: str
    title: str
    blocks: list[Block] = field(default_factory=list)
    level: int = 2
    collapsed: bool = False


@dataclass
class Report:
    """A whole report: title, verdict, sections (in order)."""

    title: str
    subtitle: str = ""
    verdict: str = "not checked"  # "PASS", "FAIL" or "not checked"
    sections: list[Section] = field(default_factory=list)
    generated: str = ""

    def figures(self) -> list[Figure]:
        return [b.figure for s in self.sections for b in s.blocks if isinstance(b, Plot)]


def fmt_num(v: Any, digits: int = 4) -> str:
    """Numbers for tables: NaN/None -> "n/a", tiny or huge values in scientific notation."""
    if v is None:
        return "n/a"
    if isinstance(v, bool):
        return str(v)
    if isinstance(v, int):
        return str(v)
    try:
        x = float(v)
    except (TypeError, ValueError):
        return str(v)
    if math.isnan(x):
        return "n/a"
    if math.isinf(x):
        return "inf" if x > 0 else "-inf"
    if x == 0:
        return "0"
    if abs(x) < 1e-3 or abs(x) >= 1e6:
        return f"{x:.{max(digits - 1, 1)}e}"
    return f"{x:.{digits}g}"
