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
    #: The figure drawn once (RGB, uint8, rows x columns x 3) at :data:`RASTER_DPI`: the HTML
    #: embeds it as PNG and the PDF places the same pixels on its page, so no figure is
    #: drawn twice (drawing is most of a report's time).
    raster: Any = None

    block: str = "plot"


#: Resolution of the figures' single drawing (dots per inch): sharp on screen and on A4.
RASTER_DPI = 110


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
    verdict: str = "not checked"  # "PASS", "FAIL", "REFUSED" or "not checked"
    sections: list[Section] = field(default_factory=list)
    generated: str = ""
    #: How the numbers were made (sync, offset, alignment, frame): on every page.
    method: str = ""
    #: The answer in a sentence or two: first thing on the page and on page 1 of the PDF.
    headline: list[str] = field(default_factory=list)

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


def _shows_exactly(text: str, v: float) -> bool:
    """False when ``text`` reads as +-1 (or 0) while ``v`` is not exactly that: a Pearson r
    of 0.9999999 printed as "1" claims a perfect correlation that is not there."""
    shown = float(text)
    return shown not in (1.0, -1.0, 0.0) or shown == v


def fmt_r(v: Any, digits: int = 6) -> str:
    """A correlation coefficient (or any value in [-1, 1]) with at least ``digits``
    significant digits and as many more as needed (up to 15) not to round to +-1 or 0."""
    if v is None or not isinstance(v, (int, float)) or math.isnan(v):
        return fmt_num(v, digits)
    text = f"{v:.{digits}g}"
    for d in range(digits, 16):
        text = f"{v:.{d}g}"
        if _shows_exactly(text, float(v)):
            break
    return text


def fmt_interval(lo: Any, hi: Any, digits: int = 5) -> str:
    """A confidence interval ``[lo, hi]`` printed with enough digits (``digits`` at least,
    up to 15) for its two ends to differ and for neither to read as +-1 unless it is:
    "[0.99999, 1]" becomes "[0.999991234, 0.999996789]". "n/a" when an end is missing."""
    ends = (lo, hi)
    if any(e is None or not isinstance(e, (int, float)) or math.isnan(e) for e in ends):
        return "n/a"
    a, b = f"{lo:.{digits}g}", f"{hi:.{digits}g}"
    for d in range(digits, 16):
        a, b = f"{lo:.{d}g}", f"{hi:.{d}g}"
        if (a != b or lo == hi) and _shows_exactly(a, lo) and _shows_exactly(b, hi):
            break
    return f"[{a}, {b}]"
