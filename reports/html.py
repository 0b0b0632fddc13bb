"""Render a :class:`uwval.reports.content.Report` into one self-contained HTML file.

Everything is inline: CSS from ``templates/report.css``, figures as base64 PNG ``data:``
URIs, no scripts, no fonts or other network resources, so the file opens offline and in CI
artifacts viewers alike.
"""

from __future__ import annotations

import base64
import io
from pathlib import Path

import numpy as np
from jinja2 import Environment, FileSystemLoader, StrictUndefined, select_autoescape
from matplotlib.figure import Figure

from uwval.errors import UwvalError
from uwval.reports.content import RASTER_DPI, Plot, Report
from uwval.reports.plots import freeze_ticks

TEMPLATES = Path(__file__).resolve().parent / "templates"


class ReportError(UwvalError):
    """The report cannot be written (output path not writable, template error)."""


def figure_png_base64(fig: Figure, dpi: int = 90) -> str:
    """A figure as base64 PNG (for ``<img src="data:image/png;base64,...">``)."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi)
    # The layout and the ticks are solved now: freeze both so that a later vector drawing
    # of the same figure neither solves the layout nor locates the ticks again. None, not
    # "none": "none" leaves a placeholder engine, and savefig makes a whole extra
    # (invisible) draw of any figure that has an engine.
    fig.set_layout_engine(None)
    freeze_ticks(fig)
    return base64.b64encode(buf.getvalue()).decode("ascii")


def rasterize(plot: Plot) -> np.ndarray:
    """Draw ``plot``'s figure once (Agg, :data:`RASTER_DPI`) and keep its RGB pixels in
    ``plot.raster``; later calls return them. Both outputs use these pixels."""
    if plot.raster is None:
        from matplotlib.backends.backend_agg import FigureCanvasAgg

        fig = plot.figure
        fig.set_dpi(RASTER_DPI)
        canvas = FigureCanvasAgg(fig)
        canvas.draw()
        plot.raster = np.asarray(canvas.buffer_rgba())[:, :, :3].copy()
    return np.asarray(plot.raster)


def png_base64(pixels: np.ndarray) -> str:
    """RGB pixels as a base64 PNG (Pillow, matplotlib's own PNG writer)."""
    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(pixels).save(buf, format="png", compress_level=3)
    return base64.b64encode(buf.getvalue()).decode("ascii")


def environment() -> Environment:
    """The jinja2 environment over ``reports/templates`` (autoescaped, strict)."""
    return Environment(
        loader=FileSystemLoader(str(TEMPLATES)),
        autoescape=select_autoescape(["html", "j2"]),
        undefined=StrictUndefined,
        trim_blocks=True,
        lstrip_blocks=True,
    )


def render_html(report: Report) -> str:
    """The report as an HTML string (figures rendered to PNG on the way)."""
    for sec in report.sections:
        for block in sec.blocks:
            if isinstance(block, Plot) and not block.png_base64:
                block.png_base64 = png_base64(rasterize(block))
    env = environment()
    css = (TEMPLATES / "report.css").read_text()
    return env.get_template("report.html.j2").render(report=report, css=css)


def write_html(report: Report, path: Path) -> Path:
    """Write the report's HTML to ``path`` (parents created)."""
    text = render_html(report)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text, encoding="utf-8")
    except OSError as exc:
        raise ReportError(f"{path}: cannot write the HTML report: {exc}") from exc
    return path
