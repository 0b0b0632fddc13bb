"""Render a :class:`uwval.reports.content.Report` into a paginated PDF (matplotlib PdfPages).

The same sections as the HTML page, in the same order: text and tables are laid out on A4
pages (long tables continue on the next page, wide ones shrink their font), each figure
gets its own page. No dependency beyond matplotlib.
"""

from __future__ import annotations

import textwrap
from datetime import datetime, timezone
from pathlib import Path

from matplotlib.backends.backend_pdf import PdfPages
from matplotlib.figure import Figure
from matplotlib.transforms import Bbox

from uwval.reports.content import Plot, Report, Section, Table, Text
from uwval.reports.html import ReportError

A4 = (8.27, 11.69)  # inches, portrait
MARGIN = 0.06  # fraction of the page
LINE = 0.018  # fraction of the page height per text line at 9 pt
ROWS_PER_PAGE = 42
CAPTION_WIDTH = 140  # characters per line of a 7 pt caption
COLOURS = {"pass": "#1a7f37", "fail": "#cf222e", "neutral": "#57606a", "": "#1f2328"}


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
        self.fig.text(
            MARGIN, 0.02, f"{self.report.title} - page {self.page}", fontsize=7, color="#57606a"
        )
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
                family="DejaVu Sans",
            )
            self.y -= LINE * size / 9

    def table(self, t: Table) -> None:
        """A table; one too wide for a readable font is split into column groups, each
        repeating the first (key) column, rather than shrunk to an unreadable size."""
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
        size, row_h = layout.font_size, 0.016 * layout.font_size / 7
        first = min(len(rows), ROWS_PER_PAGE)
        if self.heading:  # keep a section title on the page of its first table rows
            self.need(0.05 + 0.02 + row_h * (first + layout.header_lines) + 0.03)
        self.put_heading()
        # the caption goes with the last rows: never alone at the top of a page
        caption_h = (
            len(textwrap.wrap(t.caption, width=CAPTION_WIDTH)) * LINE * 7 / 9 if t.caption else 0.0
        )
        for start in range(0, len(rows), ROWS_PER_PAGE):
            chunk = rows[start : start + ROWS_PER_PAGE]
            n_lines = len(chunk) + layout.header_lines
            height = row_h * n_lines + 0.035  # title line + rows + gap below
            if start + ROWS_PER_PAGE >= len(rows):
                height += caption_h
            fig = self.need(height)
            cont = " (continued)" if start else ""
            fig.text(MARGIN, self.y, t.title + cont, fontsize=8.5, weight="bold", va="top")
            self.y -= 0.02
            ax = fig.add_axes((MARGIN, self.y - row_h * n_lines, 1 - 2 * MARGIN, row_h * n_lines))
            ax.axis("off")
            tab = ax.table(
                cellText=[[_clip(c) for c in r] for r in chunk],
                colLabels=layout.headers,
                colWidths=layout.widths,
                loc="upper left",
                cellLoc="right",
                colLoc="center",
                bbox=Bbox.from_bounds(0, 0, 1, 1),
            )
            tab.auto_set_font_size(False)
            tab.set_fontsize(size)
            for (r, c), cell in tab.get_celld().items():
                cell.set_linewidth(0.3)
                cell.PAD = 0.03
                if r == 0:
                    cell.set_height(cell.get_height() * layout.header_lines)
                    cell.set_facecolor("#f0f2f5")
                    cell.set_text_props(weight="bold")
                    continue
                if not layout.numeric[c]:
                    cell.set_text_props(ha="left")
                    setattr(cell, "_loc", "left")  # noqa: B010 (Cell has no public setter)
                if t.flag(start + r - 1, c) == "bad":
                    cell.set_facecolor("#ffebe9")
                elif t.flag(start + r - 1, c) == "warn":
                    cell.set_facecolor("#fff8c5")
            self.y -= row_h * n_lines + 0.012
        if t.caption:
            self.text(t.caption, size=7, colour="#57606a", width=CAPTION_WIDTH)
        self.y -= 0.008


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
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with PdfPages(path) as pdf:
            pager = _Pager(pdf, report)
            pager.new_page()
            pager.text(report.title, size=16, weight="bold")
            pager.text(report.subtitle, size=9, colour="#57606a")
            colour = COLOURS[
                "pass"
                if report.verdict == "PASS"
                else "fail"
                if report.verdict == "FAIL"
                else "neutral"
            ]
            pager.text(f"Verdict: {report.verdict}", size=14, weight="bold", colour=colour)
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
    """One A4 portrait page holding ``plot``: the figure scaled down as a whole (size and
    fonts, so it looks as in the HTML) to fit the margins, ``heading`` above it, its title
    and caption wrapped below it, the page footer as on text pages. Every page of the PDF
    thus has the same size. The figure is restored afterwards."""
    from matplotlib.text import Text as MplText

    fig = plot.figure
    w, h = (float(v) for v in fig.get_size_inches())
    page_w, page_h = A4
    margin = MARGIN * page_w  # inches, all sides
    caption = textwrap.wrap(f"{plot.title}. {plot.caption}", CAPTION_WIDTH - 20) or [""]
    line = 7 * 1.35 / 72  # a 7 pt caption line, inches
    usable_pt = (page_w - 2 * margin) * 72
    head = textwrap.wrap(heading, int(usable_pt / (0.65 * 11))) if heading else []
    head_h = 0.1 + 11 * 1.3 / 72 * len(head) if head else 0.0
    room_h = page_h - 2 * margin - head_h - (len(caption) + 1) * line
    scale = min(1.0, (page_w - 2 * margin) / w, room_h / h)
    texts = list(fig.findobj(MplText))
    sizes = [float(t.get_fontsize()) for t in texts]
    for t, size in zip(texts, sizes, strict=True):
        t.set_fontsize(size * scale)
    fig.set_size_inches(w * scale, h * scale)
    fw, fh = w * scale, h * scale
    x0 = -(page_w - fw) / 2  # the page's corner, in the figure's inches
    top = page_h - margin - head_h  # the figure's top edge on the page
    y0 = -(top - fh)
    notes = []
    if head:
        notes.append(
            fig.text(
                (margin + x0) / fw,
                (top + 0.08 + y0) / fh,
                "\n".join(head),
                fontsize=11,
                weight="bold",
                va="bottom",
                linespacing=1.3,
            )
        )
    notes.append(
        fig.text(
            (margin + x0) / fw,
            -line / fh,
            "\n".join(caption),
            fontsize=7,
            color="#57606a",
            va="top",
            linespacing=1.35,
        )
    )
    notes.append(
        fig.text(
            (MARGIN * page_w + x0) / fw,
            (0.02 * page_h + y0) / fh,
            f"{pager.report.title} - page {pager.page}",
            fontsize=7,
            color="#57606a",
        )
    )
    try:
        pager.pdf.savefig(fig, bbox_inches=Bbox.from_bounds(x0, y0, page_w, page_h))
    finally:
        for n in notes:
            n.remove()
        fig.set_size_inches(w, h)
        for t, size in zip(texts, sizes, strict=True):
            t.set_fontsize(size)
