"""Reports analyse only what carries signal, and open with the paper's table (issue 18)."""

from __future__ import annotations

import re
import shutil
import subprocess
from pathlib import Path

import pytest
from results_logs import VEHICLE, write_experiment

from uwval.reports import build_report
from uwval.results import load_experiment_results, roundoff_axes


@pytest.fixture(scope="module")
def experiment(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_experiment(tmp_path_factory.mktemp("sig"))


def test_roundoff_axes_are_the_ones_that_do_not_move(experiment: Path) -> None:
    table = load_experiment_results(experiment).table
    skip = roundoff_axes(table)
    # the synthetic vehicle stays at z = -2 m: its z is constant (r undefined in every run)
    assert "z" in skip[VEHICLE]
    for moving in ("x", "y", "roll", "pitch", "yaw"):
        assert moving not in skip[VEHICLE]
    # a floor above every error makes every axis round-off; none below every error
    assert roundoff_axes(table, floor=1e9)[VEHICLE] == ["x", "y", "z", "roll", "pitch", "yaw"]
    assert roundoff_axes(table, floor=0.0)[VEHICLE] == ["z"]


def test_report_skips_roundoff_and_puts_the_paper_table_after_the_verdict(
    experiment: Path, tmp_path: Path
) -> None:
    html, pdf = tmp_path / "r.html", tmp_path / "r.pdf"
    build_report(experiment, html, pdf=pdf, max_detail_runs=1)
    text = html.read_text()
    assert "The paper&#39;s validation metrics per factor level" in text
    # the answer and pass/fail per level first, then the paper's table, then the summary
    assert text.index('<section id="answer">') == text.index("<section")
    assert text.index('<section id="verdict">') < text.index('<section id="paper">')
    assert text.index('<section id="paper">') < text.index('<section id="summary">')
    assert "force = 5 N" in text and "current = 0.2 m/s" in text
    assert f"Not analysed (no ANOVA, no level plot): {VEHICLE} z" in text
    # the ANOVA tables list no round-off axis
    blocks = text.split("One-way ANOVA of MAE")[1:]
    assert len(blocks) == 2  # force and current vary
    for block in blocks:
        body = block.split("</table>")[0]
        pairs = set(re.findall(r"<tr><td[^>]*>([^<]*)</td><td[^>]*>([^<]*)</td>", body))
        assert (VEHICLE, "x") in pairs and (VEHICLE, "yaw") in pairs
        assert (VEHICLE, "z") not in pairs
    if shutil.which("pdftotext"):
        page1 = subprocess.run(
            ["pdftotext", "-f", "1", "-l", "1", "-layout", str(pdf), "-"],
            capture_output=True,
            text=True,
            check=True,
        ).stdout
        # page 1 says the answer: the verdict per level, with the thresholds
        assert "Pass or fail per factor level" in page1
        assert "force = 10 N" in page1
        assert "position" in page1 and "<= 20.00 mm" in page1  # the bound, in the header
