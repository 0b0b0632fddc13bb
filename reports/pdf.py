"""Render a :class:`uwval.reports.content.Report` into a paginated PDF (matplotlib PdfPages).

The same sections as the HTML page, in the same order: text and tables are laid out on A4
pages (long tables continue on the next page, wide ones shrink their font), each figure
gets its own page. No dependency beyond matplotlib.
"""

from __future__ import annotations

import textwrap
from datetime import datetime, timezone
from pathlib import Path

import numpy as np
from matplotlib.backends.backend_pdf import PdfPages
from matplotlib.figure import Figure
from matplotlib.lines import Line2D

from uwval.reports.content import Plot, Report, Section, Table, Text
from uwval.reports.html import ReportError

A4 = (8.27, 11.69)  # inches, portrait
MARGIN = 0.06  # fraction of the page
LINE = 0.018  # fraction of the page height per text line at 9 pt
ROWS_PER_PAGE = 42
CAPTION_WIDTH = 140  # characters per line of a 7 pt caption
COLOURS = {"pass": "#1a7f37", "fail": "#cf222e", "neutral": "#57606a", "": "#1f2328"}


def footer(fig: Figure, report: Report, page: int) -> None:
    """The foot of every page: the method line (how the numbers were made), title, page."""
    lines = textwrap.wrap(latin(report.method), CAPTION_WIDTH) if report.method else []
    fig.text(
        MARGIN,
        0.021,
        "\n".join([*lines[:2], f"{report.title} - page {page}"]),
        fontsize=6.5,
        color="#57606a",
        va="bottom",
        linespacing=1.3,
    )


class _Pager:
    """Lays text and tables out top to bottom, starting a new A4 page when one is full."""

    def __init__(self, pdf: PdfPages, report: Report) -> None:
        self.pdf = pdf
        self.report = report
        self.fig: Figure | None = None
        self.y = 1.0
        self.page = 0
        self.heading: str = ""  # a section title waiting for its first text or table

    def new_page(self) -> Figure:
        self.flush()
        self.fig = Figure(figsize=A4)
        self.page += 1
        footer(self.fig, self.report, self.page)
        self.y = 1.0 - MARGIN
        return self.fig

    def flush(self) -> None:
        if self.fig is not None:
            self.pdf.savefig(self.fig)
            self.fig.clear()
            self.fig = None

    def need(self, height: float) -> Figure:
        if self.fig is None or self.y - height < MARGIN + 0.02:
            return self.new_page()
        return self.fig

    def put_heading(self) -> None:
        """Print the pending section title (kept with the content that follows it)."""
        if self.heading:
            title, self.heading = self.heading, ""
            self.need(0.12)
            self.text(title, size=13, weight="bold")
            self.y -= 0.006

    def text(
        self,
        s: str,
        size: float = 9,
        weight: str = "normal",
        colour: str = "#1f2328",
        width: int = 110,
    ) -> None:
        self.put_heading()
        s = latin(s)
        # viz: characters per line from the font size (<= 0.65 em each, bold too), so that a
        # heading or a long run name wraps instead of running off the page
        width = min(width, int(A4[0] * (1 - 2 * MARGIN) * 72 / (0.65 * size)))
        lines = []
        for para in s.splitlines() or [""]:
            lines += textwrap.wrap(para, width=width) or [""]
        for line in lines:
            fig = self.need(LINE * size / 9)
            fig.text(
                MARGIN,
                self.y,
                line,
                fontsize=size,
                weight=weight,
                color=colour,
                va="top",
            )
            self.y -= LINE * size / 9

    def table(self, t: Table) -> None:
        """A table; one too wide for a readable font is split into column groups, each
        repeating the first (key) column, rather than shrunk to an unreadable size."""
        t = Table(
            latin(t.title),
            [latin(str(c)) for c in t.columns],
            [[latin(str(c)) for c in r] for r in t.rows],
            latin(t.caption),
            dict(t.flags),
        )
        groups = _column_groups(t)
        if len(groups) == 1:
            self._table(t)
            return
        for k, cols in enumerate(groups):
            where = {c: i for i, c in enumerate(cols)}
            self._table(
                Table(
                    f"{t.title} (columns {k + 1} of {len(groups)})",
                    [t.columns[c] for c in cols],
                    [[r[c] if c < len(r) else "" for c in cols] for r in t.rows],
                    caption=t.caption if k == len(groups) - 1 else "",
                    flags={(r, where[c]): f for (r, c), f in t.flags.items() if c in where},
                )
            )

    def _table(self, t: Table) -> None:
        rows = t.rows or [["(no rows)"] + [""] * (len(t.columns) - 1)]
        layout = _TableLayout(t.columns, rows)
        size = layout.font_size
        pitch = line_pitch(size) / (A4[1] * 72)  # one text line, fraction of the page
        first = min(len(rows), ROWS_PER_PAGE)
        if self.heading:  # keep a section title on the page of its first table rows
            self.need(0.05 + 0.02 + pitch * (first + layout.header_lines) + 0.03)
        self.put_heading()
        # the caption goes with the last rows: never alone at the top of a page
        caption_h = (
            len(textwrap.wrap(t.caption, width=CAPTION_WIDTH)) * LINE * 7 / 9 if t.caption else 0.0
        )
        for start in range(0, len(rows), ROWS_PER_PAGE):
            chunk = rows[start : start + ROWS_PER_PAGE]
            height = pitch * (len(chunk) + layout.header_lines) + 0.04
            if start + ROWS_PER_PAGE >= len(rows):
                height += caption_h
            fig = self.need(height)
            cont = " (continued)" if start else ""
            fig.text(MARGIN, self.y, t.title + cont, fontsize=8.5, weight="bold", va="top")
            self.y -= 0.02
            flags = {
                (r - start, c): f
                for (r, c), f in t.flags.items()
                if start <= r < start + len(chunk)
            }
            self.y = _draw_columns(fig, self.y, layout, chunk, flags, pitch)
            self.y -= 0.01
        if t.caption:
            self.text(t.caption, size=7, colour="#57606a", width=CAPTION_WIDTH)
        self.y -= 0.008


#: Ascender + descender of Helvetica per point of font size (AFM: 718 and 207 per 1000):
#: with a numeric linespacing, matplotlib spaces every line by linespacing x this, whatever
#: glyphs it holds, so the columns of a table (one text each) stay row-aligned.
LP_HEIGHT = (718 + 207) / 1000

#: Characters outside the PDF core fonts' encoding (cp1252), as the pages write them.
_NOT_IN_CORE_FONTS = {"≤": "<=", "≥": ">=", "η": "eta", "−": "-", "→": "->"}


def latin(text: str) -> str:
    """``text`` in the PDF core fonts' encoding: "≤" as "<=", "η²" as "eta²", anything
    else outside cp1252 as "?" (the core fonts cannot draw it)."""
    for k, v in _NOT_IN_CORE_FONTS.items():
        text = text.replace(k, v)
    return text.encode("cp1252", "replace").decode("cp1252")


#: Text colours of flagged table cells in the PDF.
FLAG_COLOURS = {"bad": "#cf222e", "warn": "#9a6700", "good": "#1a7f37", "strong": "#1f2328"}


def line_pitch(size: float, spacing: float = 1.25) -> float:
    """Distance (points) between two lines of a multi-line text at ``size`` pt, as matplotlib
    lays them out: ``spacing`` x (ascender + descender) of Helvetica (the PDF core font
    the pages are written in)."""
    return float(LP_HEIGHT * size * spacing)


def _draw_columns(
    fig: Figure,
    top: float,
    layout: _TableLayout,
    rows: list[list[str]],
    flags: dict[tuple[int, int], str],
    pitch: float,
) -> float:
    """Draw a table as one multi-line text per column (plus one per flag colour), rules
    above and below the header and below the last row; returns the y below the table.
    A text per column, not per cell: a PDF table of a few thousand cells draws in tens of
    milliseconds instead of seconds."""
    width = 1 - 2 * MARGIN
    size = layout.font_size
    head_h = pitch * layout.header_lines
    body_top = top - head_h - 0.004
    lefts = np.concatenate([[0.0], np.cumsum(layout.widths)]) * width + MARGIN
    common = dict(fontsize=size, va="top", linespacing=1.25)
    for c in range(len(layout.headers)):
        left, right = float(lefts[c]), float(lefts[c + 1])
        numeric = layout.numeric[c]
        x, ha = (right - 0.004, "right") if numeric else (left + 0.002, "left")
        fig.text(x, top, layout.headers[c], ha=ha, weight="bold", **common)  # type: ignore[arg-type]
        by_colour: dict[str, list[str]] = {}
        plain = []
        for r, row in enumerate(rows):
            cell = _clip(row[c]) if c < len(row) else ""
            flag = flags.get((r, c), "")
            colour = FLAG_COLOURS.get(flag)
            plain.append("" if colour else cell)
            for col in {*FLAG_COLOURS.values()}:
                by_colour.setdefault(col, [])
            for col in by_colour:
                by_colour[col].append(cell if col == colour else "")
        fig.text(x, body_top, "\n".join(plain), ha=ha, **common)  # type: ignore[arg-type]
        for col, lines in by_colour.items():
            if any(lines):
                fig.text(x, body_top, "\n".join(lines), ha=ha, color=col, weight="bold", **common)  # type: ignore[arg-type]
    bottom = body_top - pitch * len(rows)
    for y, lw in ((top + 0.002, 0.8), (body_top + 0.002, 0.5), (bottom - 0.002, 0.8)):
        fig.add_artist(Line2D([MARGIN, 1 - MARGIN], [y, y], lw=lw, color="#57606a"))
    return bottom - 0.006


class _TableLayout:
    """Column widths from the longest cell, headers wrapped to them, one font size that
    makes the whole table fit the page width (so no header runs into its neighbour)."""

    def __init__(self, columns: list[str], rows: list[list[str]]) -> None:
        ncols = max(1, len(columns))
        chars = []
        for c in range(ncols):
            cells = [len(_clip(r[c])) for r in rows if c < len(r)]
            head = str(columns[c]) if c < len(columns) else ""
            longest_word = max((len(w) for w in head.split()), default=1)
            chars.append(max([*cells, longest_word, 3]))
        self.headers = []
        for c in range(ncols):
            head = str(columns[c]) if c < len(columns) else ""
            self.headers.append("\n".join(textwrap.wrap(head, width=max(chars[c], 6))) or head)
        self.header_lines = max(1, *(h.count("\n") + 1 for h in self.headers))
        self.chars = chars  # longest line per column, in characters
        widths = [w + 1.5 for w in chars]  # + cell padding
        total = sum(widths)
        self.widths = [w / total for w in widths]
        # DejaVu Sans averages ~0.6 em per character; the usable width is A4 minus margins
        usable_pt = A4[0] * (1 - 2 * MARGIN) * 72
        self.font_size = max(4.0, min(7.0, usable_pt / (0.6 * total)))
        self.numeric = [all(_is_number(r[c]) for r in rows if c < len(r)) for c in range(ncols)]


def _is_number(cell: str) -> bool:
    text = str(cell).strip().split(" ")[0]
    if text in ("", "n/a", "-", "nan"):
        return True
    try:
        float(text)
    except ValueError:
        return False
    return True


#: Smallest table font (pt) before a wide table is split into column groups.
MIN_TABLE_FONT = 6.0


def _column_groups(t: Table) -> list[list[int]]:
    """Column index groups that each fit the page at MIN_TABLE_FONT (first column in all)."""
    n = len(t.columns)
    if n <= 2:
        return [list(range(n))]
    chars = _TableLayout(t.columns, t.rows or [[""] * n]).chars
    budget = A4[0] * (1 - 2 * MARGIN) * 72 / (0.6 * MIN_TABLE_FONT)
    groups: list[list[int]] = []
    current = [0]
    used = chars[0] + 1.5
    for c in range(1, n):
        need = chars[c] + 1.5
        if len(current) > 1 and used + need > budget:
            groups.append(current)
            current, used = [0], chars[0] + 1.5
        current.append(c)
        used += need
    groups.append(current)
    return groups


def _clip(s: str, n: int = 72) -> str:
    s = str(s)
    return s if len(s) <= n else s[: n - 3] + "..."


def write_pdf(report: Report, path: Path) -> Path:
    """Write the report as a PDF to ``path``; returns the path."""
    import logging

    import matplotlib

    # the core Helvetica's AFM says "Medium" where matplotlib asks for "normal": the same
    # face, but font_manager logs a warning per lookup
    font_log = logging.getLogger("matplotlib.font_manager")
    level = font_log.level
    font_log.setLevel(logging.ERROR)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        # the PDF core fonts (Helvetica): no glyphs to lay out and embed per line of text,
        # which made text pages most of the PDF's time
        with matplotlib.rc_context({"pdf.use14corefonts": True}), PdfPages(path) as pdf:
            pager = _Pager(pdf, report)
            pager.new_page()
            pager.text(report.title, size=16, weight="bold")
            pager.text(report.subtitle, size=9, colour="#57606a")
            colour = COLOURS[
                "pass"
                if report.verdict == "PASS"
                else "fail"
                if report.verdict in ("FAIL", "REFUSED")
                else "neutral"
            ]
            pager.text(f"Verdict: {report.verdict}", size=14, weight="bold", colour=colour)
            for line in report.headline:  # the answer, in a sentence, on page 1
                pager.y -= 0.006
                pager.text(line, size=10.5, weight="bold")
            pager.y -= 0.006
            if report.method:
                pager.text(report.method, size=8.5)
            pager.text(f"generated {report.generated}", size=8, colour="#57606a")
            pager.y -= 0.01
            for sec in report.sections:
                _section(pager, sec)
            pager.put_heading()
            pager.flush()
            meta = pdf.infodict()
            meta["Title"] = report.title
            meta["Subject"] = f"verdict {report.verdict}"
            meta["Creator"] = "uwval"
            meta["CreationDate"] = datetime.now(timezone.utc)
    except OSError as exc:
        raise ReportError(f"{path}: cannot write the PDF report: {exc}") from exc
    finally:
        font_log.setLevel(level)
    return path


def _section(pager: _Pager, sec: Section) -> None:
    pager.heading = sec.title
    for b in sec.blocks:
        if isinstance(b, Text):
            if b.kind == "list":
                for line in b.text:
                    pager.text(f"- {line}", colour=COLOURS.get(b.css, COLOURS[""]))
            else:
                pager.text(
                    str(b.text),
                    colour=COLOURS.get(b.css, COLOURS[""]),
                    weight="bold" if b.css in ("pass", "fail") else "normal",
                )
        elif isinstance(b, Table):
            pager.table(b)
        elif isinstance(b, Plot):
            pager.flush()  # a figure gets an A4 page of its own (viz: _figure_page)
            heading, pager.heading = pager.heading, ""
            pager.page += 1
            _figure_page(pager, b, heading)


def _figure_page(pager: _Pager, plot: Plot, heading: str) -> None:
    """One A4 portrait page holding ``plot``: its pixels (drawn once, shared with the HTML
    page: :func:`uwval.reports.html.rasterize`) scaled to fit the margins, ``heading``
    above, its title and caption wrapped below, the footer as on text pages."""
    from uwval.reports.html import rasterize

    pixels = rasterize(plot)
    page = Figure(figsize=A4)
    page_w, page_h = A4
    margin = MARGIN * page_w  # inches, all sides
    caption = textwrap.wrap(latin(f"{plot.title}. {plot.caption}"), CAPTION_WIDTH - 20) or [""]
    line = 7 * 1.35 / 72  # a 7 pt caption line, inches
    head = (
        textwrap.wrap(latin(heading), int((page_w - 2 * margin) * 72 / (0.65 * 11)))
        if heading
        else []
    )
    head_h = 0.1 + 11 * 1.3 / 72 * len(head) if head else 0.0
    img_h_px, img_w_px = pixels.shape[:2]
    room_w = page_w - 2 * margin
    room_h = page_h - 2 * margin - head_h - (len(caption) + 1) * line - 0.3
    scale = min(room_w / img_w_px, room_h / img_h_px)  # inches per pixel
    w, h = img_w_px * scale, img_h_px * scale
    top = page_h - margin - head_h
    if head:
        page.text(margin / page_w, (top + 0.08) / page_h, "\n".join(head), fontsize=11,
                  weight="bold", va="bottom", linespacing=1.3)  # fmt: skip
    ax = page.add_axes((margin / page_w, (top - h) / page_h, w / page_w, h / page_h))
    ax.imshow(pixels, interpolation="none", aspect="auto")
    ax.axis("off")
    page.text(margin / page_w, (top - h - line) / page_h, "\n".join(caption), fontsize=7,
              color="#57606a", va="top", linespacing=1.35)  # fmt: skip
    footer(page, pager.report, pager.page)
    pager.pdf.savefig(page)
