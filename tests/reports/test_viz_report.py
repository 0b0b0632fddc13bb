"""Issue 16 (viz): the report of one log carries the error histograms and the trajectory
coloured by the error; its PDF has one page size (A4 portrait, figures scaled onto it, not
pages at the figures' own sizes); Pearson CIs are printed with enough digits to say something.
"""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from results_logs import write_pair_log

A4_PT = (595.44, 841.68)


def test_ci_and_r_digits() -> None:
    from uwval.reports.content import fmt_interval, fmt_r

    # the "[1, 1]": ends of 0.99999x now differ and neither reads as 1
    assert fmt_interval(0.9999991234, 0.9999996789) == "[0.9999991, 0.9999997]"
    assert fmt_interval(0.98, 0.995) == "[0.98, 0.995]"
    assert fmt_interval(-0.9999999991, -0.9999999) == "[-0.999999999, -0.9999999]"
    assert fmt_interval(1.0, 1.0) == "[1, 1]"  # a true perfect correlation stays as it is
    assert fmt_interval(None, 0.5) == "n/a"
    assert fmt_interval(float("nan"), 0.5) == "n/a"
    assert fmt_r(0.99999999123) == "0.99999999"
    assert fmt_r(0.123456789) == "0.123457"
    assert fmt_r(1.0) == "1"
    assert fmt_r(None) == "n/a"


def _media_boxes(pdf: bytes) -> list[tuple[float, float]]:
    boxes = re.findall(rb"/MediaBox\s*\[\s*0\s+0\s+([\d.]+)\s+([\d.]+)\s*\]", pdf)
    return [(float(w), float(h)) for w, h in boxes]


def test_one_log_report_has_the_error_figures_and_one_pdf_page_size(tmp_path: Path) -> None:
    log = write_pair_log(tmp_path / "run.mcap", lag_s=0.02, noise=0.002, seed=16, duration=2.0)
    html_out, pdf_out = tmp_path / "out" / "r.html", tmp_path / "r.pdf"
    res = subprocess.run(
        [sys.executable, "-m", "uwval", "report", str(log), "-o", str(html_out), "--pdf",
         str(pdf_out)],
        capture_output=True,
        text=True,
        timeout=180,
    )  # fmt: skip
    assert res.returncode == 0, res.stderr
    html = html_out.read_text()
    for title in (
        "Error histograms: run / model_rov_pose",
        "Trajectory coloured by the position error: run / model_rov_pose",
    ):
        assert f'<img alt="{title}"' in html
    # the CI column: two different ends, none shown as a bare 1 unless it is exactly 1
    cis = re.findall(r"<td[^>]*>\[(-?[\d.e-]+), (-?[\d.e-]+)\]</td>", html)
    assert len(cis) >= 6
    for lo, hi in cis:
        assert lo != hi
    pdf = pdf_out.read_bytes()
    boxes = _media_boxes(pdf)
    n_figures = html.count("<img ")
    assert len(boxes) > n_figures  # text pages + one page per figure
    assert set(boxes) == {A4_PT}, sorted(set(boxes))
    if shutil.which("pdftotext"):
        text = subprocess.run(
            ["pdftotext", "-layout", str(pdf_out), "-"], capture_output=True, text=True, timeout=60
        ).stdout
        assert "Error histograms: run / model_rov_pose" in text
        assert "page 2" in text  # figure pages are numbered like the text pages


@pytest.mark.skipif(shutil.which("pdftoppm") is None, reason="pdftoppm not installed")
def test_figure_pages_are_not_cut(tmp_path: Path) -> None:
    # the whole figure is on its page: margins left white all round, ink in the middle
    import numpy as np
    from matplotlib.backends.backend_pdf import PdfPages
    from PIL import Image

    from uwval.reports.content import Plot, Report
    from uwval.reports.pdf import _figure_page, _Pager
    from uwval.reports.plots import _new_figure

    fig = _new_figure(11, 13)  # taller and wider than A4's usable area
    ax = fig.subplots()
    ax.plot([0, 1], [0, 1], lw=8, color="black")
    ax.set_xlim(0, 1)
    ax.set_ylim(0, 1)
    out = tmp_path / "p.pdf"
    heading = "Run " + "-".join(f"bluerov2_heavy-force={i}_current=0.{i}" for i in range(4))
    with PdfPages(out) as pdf:
        pager = _Pager(pdf, Report("t"))
        _figure_page(pager, Plot("a plot", fig, "its caption " * 30), heading)
    assert _media_boxes(out.read_bytes()) == [A4_PT]
    assert tuple(fig.get_size_inches()) == (11, 13)  # restored for any later use
    subprocess.run(
        ["pdftoppm", "-r", "40", "-png", str(out), str(tmp_path / "pg")], check=True, timeout=60
    )
    (png,) = tmp_path.glob("pg*.png")
    a = np.asarray(Image.open(png).convert("L"))
    ink = np.argwhere(a < 128)
    h, w = a.shape
    top, left = ink.min(axis=0)
    bottom, right = ink.max(axis=0)
    assert left > 0.02 * w and right < 0.98 * w
    assert top > 0.02 * h and bottom < 0.98 * h
    # the diagonal is drawn corner to corner of its axes, so it spans most of the width
    assert right - left > 0.6 * w


def test_long_titles_wrap_inside_the_page() -> None:
    # the issue: run titles cut at the page edge. Headings (13 pt) and the report title
    # (16 pt) wrap by their own font size; every line ends inside the right margin.
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.backends.backend_pdf import PdfPages

    from uwval.reports.content import Report
    from uwval.reports.pdf import A4, MARGIN, _Pager

    name = "Run " + "-".join(f"bluerov2_heavy-force={i}_current=0.{i}" for i in range(4))
    with PdfPages("/dev/null") as pdf:
        pager = _Pager(pdf, Report("t"))
        pager.new_page()
        for size in (9, 13, 16):
            pager.text(name, size=size, weight="bold")
        fig = pager.fig
        assert fig is not None
        renderer = FigureCanvasAgg(fig).get_renderer()
        right = A4[0] * (1 - MARGIN) * fig.dpi
        texts = [t for t in fig.texts if t.get_text().strip()]
        assert len(texts) > 6  # wrapped onto several lines
        for t in texts:
            assert t.get_window_extent(renderer).x1 <= right, t.get_text()
        pager.fig = None  # nothing to save
