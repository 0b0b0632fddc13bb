"""The HTML/PDF report: content, self-containment, real headless Chromium, pdftoppm pages."""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import pytest

from uwval.gate import parse_thresholds
from uwval.reports import build_report
from uwval.reports.builder import sha256_of

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from browser import _chromium, _console_errors, _ink
from results_logs import VEHICLE, write_experiment, write_pair_log

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
PDFTOPPM = shutil.which("pdftoppm")


@pytest.fixture(scope="module")
def experiment(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_experiment(tmp_path_factory.mktemp("report-exp"))


@pytest.fixture(scope="module")
def experiment_report(
    experiment: Path, tmp_path_factory: pytest.TempPathFactory
) -> tuple[Path, Path, str]:
    out = tmp_path_factory.mktemp("report-out")
    outcome = build_report(
        experiment, out / "report.html", pdf=out / "report.pdf", max_detail_runs=2
    )
    assert outcome.n_runs == 8
    return outcome.html, out / "report.pdf", outcome.html.read_text()


class _Refs(HTMLParser):
    """Every URL-bearing attribute and every tag name of a page."""

    def __init__(self) -> None:
        super().__init__()
        self.urls: list[str] = []
        self.tags: list[str] = []
        self.ids: list[str] = []

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        self.tags.append(tag)
        for k, v in attrs:
            if k in ("src", "href", "action", "poster", "data") and v is not None:
                self.urls.append(v)
            if k == "id" and v:
                self.ids.append(v)


def _refs(html: str) -> _Refs:
    p = _Refs()
    p.feed(html)
    return p


# ----------------------------------------------------------------------------- content
def test_experiment_report_sections_and_self_containment(
    experiment_report: tuple[Path, Path, str],
) -> None:
    _, _, html = experiment_report
    refs = _refs(html)
    # self-contained: images are data: URIs, links are in-page anchors, nothing else
    assert refs.urls
    for url in refs.urls:
        assert url.startswith(("data:", "#")), url
    assert "script" not in refs.tags
    assert not re.search(r"url\((?!data:)", html)  # no CSS-fetched resources
    assert "@import" not in html
    for section in (
        "answer",
        "verdict",
        "sensitivity",
        "paper",
        "summary",
        "level-plots",
        "one-way",
        "two-way",
        "runs",
        "bridge",
        "provenance",
    ):
        assert section in refs.ids, section
    # the answer first, then pass/fail; the one-way view is secondary (after the summary)
    assert refs.ids.index("answer") < refs.ids.index("verdict") < refs.ids.index("summary")
    assert refs.ids.index("summary") < refs.ids.index("one-way")
    assert "One-way ANOVA of MAE across levels of current" in html
    assert "of torque" not in html  # torque does not vary: no one-way table of it
    assert "Pearson r" in html
    assert "MAE" in html
    assert "Absolute error" in html
    # per-run details for the 2 worst runs (distinct cells of the design), 2 plots each
    run_sections = [i for i in refs.ids if i.startswith("run-")]
    assert len(run_sections) == 2
    for title in ("Error over time", "Trajectory coloured by the position error"):
        assert html.count(f'alt="{title}: ') == 2
    assert "per-run plots shown for the 2 worst of 8 runs" in html
    # the worst: the largest lag is at current 0.2 (write_experiment: 0.3 s per m/s)
    assert all("current0.2" in i for i in run_sections)
    # bridge statistics from the manifest, summarised over the runs (ms, counts)
    assert "latency_mean" in html
    assert "dropped" in html


def test_provenance_lists_inputs_with_their_sha256(
    experiment: Path, experiment_report: tuple[Path, Path, str]
) -> None:
    import uwval

    _, _, html = experiment_report
    assert uwval.__version__ in html
    for name in ("manifest.json", "comparisons.json"):
        assert name in html
    log = sorted((experiment / "runs").glob("*.mcap"))[0]
    assert sha256_of(log) in html
    assert sha256_of(experiment / "manifest.json") in html


def test_verdict_fail_lists_the_regressions(tmp_path: Path) -> None:
    log = write_pair_log(tmp_path / "laggy.mcap", lag_s=0.2)
    th = parse_thresholds(
        {
            "threshold": [
                {
                    "name": "tight x",
                    "metric": "mae",
                    "axes": ["x"],
                    "topics": [VEHICLE],
                    "max": 0.01,
                }
            ]
        }
    )
    outcome = build_report(log, tmp_path / "r.html", thresholds=th)
    assert outcome.gate is not None
    assert not outcome.gate.passed
    html = outcome.html.read_text()
    assert 'class="verdict-badge fail">FAIL<' in html
    assert "What regressed" in html
    assert "tight x" in html
    assert 'class="bad"' in html
    ok = build_report(log, tmp_path / "ok.html", thresholds=None)
    assert ok.gate is None
    assert "not gated" in ok.html.read_text()


def test_manifest_without_results_is_compared_on_the_fly(tmp_path: Path) -> None:
    root = write_experiment(tmp_path / "e", compare=False, reps=1)
    outcome = build_report(root, tmp_path / "r.html", max_detail_runs=1)
    assert outcome.n_runs == 4
    assert set(outcome.table.runs) == {p.stem for p in (root / "runs").glob("*.mcap")}


# ----------------------------------------------------------------------------- CLI
def test_cli_report_on_a_single_log(tmp_path: Path) -> None:
    log = write_pair_log(tmp_path / "run.mcap", lag_s=0.02)
    res = subprocess.run(
        [
            sys.executable,
            "-m",
            "uwval",
            "report",
            str(log),
            "-o",
            str(tmp_path / "out" / "r.html"),
            "--pdf",
            str(tmp_path / "r.pdf"),
            "--results",
            str(tmp_path / "res.csv"),
        ],
        capture_output=True,
        text=True,
        timeout=180,
    )
    assert res.returncode == 0, res.stderr
    assert "verdict PASS" in res.stdout
    html = (tmp_path / "out" / "r.html").read_text()
    assert "Run run" in html
    assert "Trajectory overlay: run / model_rov_pose" in html
    assert (tmp_path / "r.pdf").read_bytes().startswith(b"%PDF")
    assert (tmp_path / "res.csv").read_text().startswith("run,topic,axis,metric,value")
    missing = subprocess.run(
        [
            sys.executable,
            "-m",
            "uwval",
            "report",
            str(tmp_path / "nope.mcap"),
            "-o",
            str(tmp_path / "x.html"),
        ],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert missing.returncode == 2
    assert "nope.mcap" in missing.stderr
    assert "Traceback" not in missing.stderr


# ----------------------------------------------------------------------------- Chromium


@pytest.mark.skipif(CHROMIUM is None, reason="chromium not installed (.ci/run installs it)")
def test_html_loads_in_headless_chromium_without_console_errors(
    experiment_report: tuple[Path, Path, str], tmp_path: Path
) -> None:
    page, _, _ = experiment_report
    shot, log = _chromium(page, tmp_path)
    assert _console_errors(log) == []
    ink, std = _ink(shot)
    assert ink > 0.02, "screenshot is blank"
    assert std > 10


@pytest.mark.skipif(CHROMIUM is None, reason="chromium not installed (.ci/run installs it)")
def test_the_chromium_checks_do_catch_errors_and_blank_pages(tmp_path: Path) -> None:
    # negative control: the same checks flag a page with a script error and no content
    bad = tmp_path / "bad.html"
    bad.write_text("<!DOCTYPE html><html><body><script>undefinedFunction();</script></body></html>")
    shot, log = _chromium(bad, tmp_path)
    assert _console_errors(log), "a script error must show up as a console message"
    ink, _ = _ink(shot)
    assert ink < 0.02


# ----------------------------------------------------------------------------- PDF
@pytest.mark.skipif(PDFTOPPM is None, reason="pdftoppm not installed (poppler-utils)")
def test_pdf_pages_render_and_are_not_blank(
    experiment_report: tuple[Path, Path, str], tmp_path: Path
) -> None:
    _, pdf, html = experiment_report
    assert PDFTOPPM is not None
    res = subprocess.run(
        [PDFTOPPM, "-r", "30", "-png", str(pdf), str(tmp_path / "page")],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert res.returncode == 0, res.stderr
    pages = sorted(tmp_path.glob("page-*.png"))
    # text pages + one page per figure: at least as many pages as figures in the HTML
    n_figures = html.count("<img ")
    assert len(pages) > n_figures
    for p in pages:
        ink, std = _ink(p)
        assert ink > 0.005, f"{p.name} is blank"
        assert std > 3, f"{p.name} is blank"
    text = (
        subprocess.run(["pdftotext", str(pdf), "-"], capture_output=True, text=True, timeout=60)
        if shutil.which("pdftotext")
        else None
    )
    if text is not None and text.returncode == 0:
        for words in (
            "Verdict",
            "Pass or fail: per factor level and per threshold rule",
            "Summary: absolute error, MAE and Pearson r",
            "Secondary view: one factor at a time",
            "Provenance",
        ):
            assert words in text.stdout


def test_cli_report_names_a_corrupt_manifest(tmp_path: Path) -> None:
    (tmp_path / "exp").mkdir()
    (tmp_path / "exp" / "manifest.json").write_text('{"runs": [')
    res = subprocess.run(
        [
            sys.executable,
            "-m",
            "uwval",
            "report",
            str(tmp_path / "exp"),
            "-o",
            str(tmp_path / "r.html"),
        ],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert res.returncode == 2
    assert "manifest.json: not valid JSON" in res.stderr
    assert not (tmp_path / "r.html").exists()


# ----------------------------------------------------------------------------- readability
def test_factor_axes_carry_units_and_leave_the_caption_strips_free(experiment: Path) -> None:
    """force in N, torque in N m, current in m/s on every factor axis; after the layout is
    solved (the HTML render) no axis, label or title reaches into the strips the PDF uses
    for the caption (bottom) and the section heading (top)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    from uwval.reports import plots
    from uwval.reports.html import figure_png_base64
    from uwval.results import load_experiment_results

    table = load_experiment_results(experiment).table
    box = plots.box_mae_figure(table, "current", VEHICLE)
    effects = plots.main_effects_figure(table, VEHICLE)
    assert {ax.get_xlabel() for ax in box.axes} == {"current (m/s)"}
    assert {ax.get_xlabel() for ax in effects.axes} >= {"force (N)", "current (m/s)"}
    assert {ax.get_ylabel() for ax in box.axes} == {"MAE (m)", "MAE (deg)"}
    for fig in (box, effects):
        figure_png_base64(fig)
        renderer = FigureCanvasAgg(fig).get_renderer()
        h_px = fig.get_size_inches()[1] * fig.dpi
        for ax in fig.axes:
            if not ax.get_visible():
                continue
            bb = ax.get_tightbbox(renderer)
            assert bb is not None
            assert bb.y0 >= plots.CAPTION_STRIP_IN * fig.dpi - 1, ax.get_title()
            assert bb.y1 <= h_px - plots.HEADING_STRIP_IN * fig.dpi + 1, ax.get_title()


def test_pinned_ticks_keep_labels_and_offset_text(experiment: Path) -> None:
    """The PDF redraw uses the ticks of the HTML draw, including a '1e-16'-style offset."""
    from uwval.reports import plots
    from uwval.reports.html import figure_png_base64

    fig = plots._new_figure(4, 3)
    ax = fig.subplots()
    ax.plot([0, 1, 2], np.array([1.0, 3.0, 2.0]) * 1e-16)
    figure_png_base64(fig)
    labels = [t.get_text() for t in ax.yaxis.get_majorticklabels()]
    offset = ax.yaxis.get_major_formatter().get_offset()
    assert offset  # the small values need an offset / exponent label
    import io

    fig.savefig(io.BytesIO(), format="pdf")
    assert [t.get_text() for t in ax.yaxis.get_majorticklabels()] == labels
    assert ax.yaxis.get_major_formatter().get_offset() == offset


def test_pdf_tables_fit_the_page_and_headings_stay_with_their_tables(
    experiment_report: tuple[Path, Path, str],
) -> None:
    from uwval.reports.pdf import A4, MARGIN, _TableLayout

    cols = [
        "topic",
        "axis",
        "unit",
        "MAE mean",
        "MAE worst",
        "max |error| worst",
        "p95 |error| worst",
        "Pearson r mean",
        "Pearson r lowest",
        "r undefined",
    ]
    rows = [
        [
            "gui_camera_pose",
            "pitch",
            "deg",
            "4.603e-15",
            "5.077e-15",
            "2.487e-14",
            "1.421e-14",
            "0.999996",
            "0.999982",
            "8",
        ]
    ]
    lay = _TableLayout(cols, rows)
    usable_pt = A4[0] * (1 - 2 * MARGIN) * 72
    for c, w in enumerate(lay.widths):
        longest = max(len(line) for line in [*lay.headers[c].split("\n"), rows[0][c]])
        # each column is wide enough for its longest line at ~0.6 em per character
        assert w * usable_pt >= 0.6 * lay.font_size * longest * 0.999, cols[c]
    assert lay.numeric[3] and not lay.numeric[0]
    if shutil.which("pdftotext") is None:
        return
    _, pdf, _ = experiment_report
    pages = subprocess.run(
        ["pdftotext", "-layout", str(pdf), "-"], capture_output=True, text=True, timeout=60
    ).stdout.split("\f")
    for title, first_table in (
        ("Pass or fail: per factor level and per", "Pass or fail per factor level"),
        ("Secondary view: one factor at a time", "Per level of force"),
    ):
        page = next(p for p in pages if title in p)
        assert first_table in page, f"{title!r} is separated from its table"


def test_wide_pdf_tables_split_into_readable_column_groups() -> None:
    from uwval.reports.content import Table
    from uwval.reports.pdf import MIN_TABLE_FONT, _column_groups, _TableLayout

    cols = ["run", *[f"statistic_number_{i}" for i in range(21)]]
    rows = [
        [f"default-0{r}-force=5_torque=0.5_current=0.3", *[f"{r * i:.4f}" for i in range(21)]]
        for r in range(8)
    ]
    t = Table("Per run", cols, rows, flags={(2, 5): "bad"})
    groups = _column_groups(t)
    assert len(groups) > 1
    assert all(g[0] == 0 for g in groups)
    assert sorted({c for g in groups for c in g}) == list(range(len(cols)))
    for g in groups:
        lay = _TableLayout([cols[c] for c in g], [[r[c] for c in g] for r in rows])
        assert lay.font_size >= MIN_TABLE_FONT
    assert _column_groups(Table("narrow", ["a", "b", "c"], [["1", "2", "3"]])) == [[0, 1, 2]]


def test_bridge_bars_are_labelled_with_short_run_ids() -> None:
    from uwval.reports import plots

    names = [f"default-0{i}-force=5_torque=0.5_current=0.{i}" for i in range(4)]
    assert plots.short_run_labels(names) == ["00", "01", "02", "03"]
    assert plots.short_run_labels(["r1", "r2"]) == ["r1", "r2"]
    assert plots.short_run_labels(["one-very-long-name-a", "another-very-long-name"]) == ["0", "1"]
    fig = plots.bridge_figure(
        {n: {"latency_mean_s": 0.01 * i, "dropped": i} for i, n in enumerate(names)}
    )
    assert fig is not None
    ticks = [t.get_text() for t in fig.axes[0].get_xticklabels()]
    assert ticks == ["00", "01", "02", "03"]
