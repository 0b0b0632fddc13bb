"""The report answers at a glance (issue 33.4, 31.3/5): the study's sentence and effect sizes
first (analysis.json), the Gazebo-model sensitivity (sensitivity.json), pass or fail per factor
level and per rule with the bounds shown, one number format, the method on every page, tables
that fit 1400 px (real headless Chromium) and A4 (pdftotext)."""

from __future__ import annotations

import json
import re
import shutil
import subprocess
from pathlib import Path

import pytest
from browser import CHROMIUM, DevTools
from cli_runner import run_uwval
from results_logs import VEHICLE, write_experiment

from uwval.reports import build_report
from uwval.reports.numbers import (
    Quantity,
    fmt,
    fmt_correlation,
    fmt_correlation_interval,
    fmt_p,
)
from uwval.results import load_experiment_results

PDFTOTEXT = shutil.which("pdftotext")
ANSWER = (
    "Unity shows Gazebo's pose 12.4 ms late (95 % CI 12.1-12.7 ms); current explains "
    "91 % of the x error."
)


def _analysis(factors: dict[str, list[float]]) -> dict[str, object]:
    """An analysis.json as docs/analysis.md (study) specifies it, x MAE only."""
    levels = {
        f: [
            {
                "level": lv,
                "n": 4,
                "mean": 0.0031 + 0.001 * i,
                "ci95": [0.0029 + 0.001 * i, 0.0033 + 0.001 * i],
            }
            for i, lv in enumerate(lvls)
        ]
        for f, lvls in factors.items()
    }
    terms = [
        {"term": "force", "df": 1, "sum_sq": 1e-6, "f": 12.3, "p": 1e-17, "partial_eta_sq": 0.07},
        {
            "term": "current",
            "df": 1,
            "sum_sq": 1e-5,
            "f": 80.1,
            "p": 3.2e-5,
            "partial_eta_sq": 0.91,
            "eta_sq": 0.913,
        },
        {
            "term": "force:current",
            "df": 1,
            "sum_sq": 1e-8,
            "f": 1.1,
            "p": 0.31,
            "partial_eta_sq": 0.02,
        },
    ]
    return {
        "schema": "uwval.analysis/1",
        "n_runs": 8,
        "factors": factors,
        "replicates": {"min": 2, "max": 2},
        "answer": ANSWER,
        "lag": {VEHICLE: {"n_runs": 8, "fitted_s_mean": 0.0124, "fitted_s_min": 0.0120,
                          "fitted_s_max": 0.0129, "explained_mean": 0.98,
                          "measured_s_mean": 0.0121}},
        "topics": {VEHICLE: {"x": {
            "mae": {"model": "value ~ force + current + force:current", "n": 8,
                    "df_residual": 4, "note": "", "terms": terms, "levels": levels},
            "pearson_r": {"terms": [], "levels": {}, "saturated": True,
                          "saturated_why": "every r is above 0.999"},
        }}},
    }  # fmt: skip


SENSITIVITY = {
    "schema": "uwval-sensitivity/1",
    "vehicle": "bluerov2_heavy",
    "duration_s": 4.0,
    "reference_input": {"force_n": 10.0, "torque_nm": 0.25, "current_ms": 0.1},
    "baseline": {"coriolis": "fixed", "added_mass": "implicit", "ca_sign": "fossen",
                 "label": "the default experiment's model"},
    "variants": [
        {"name": "coriolis", "label": "Coriolis entries of gz-sim 8.0-8.11",
         "model": {"coriolis": "legacy"}, "diverged": False, "diverged_at_s": None,
         "position_max_m": 0.0012, "position_final_m": 0.0011, "yaw_max_deg": 0.3,
         "yaw_final_deg": 0.25, "rotation_max_deg": 0.4},
        {"name": "added_mass", "label": "explicit added mass (the plugin's)",
         "model": {"added_mass": "explicit"}, "diverged": True, "diverged_at_s": 1.25,
         "position_max_m": None, "position_final_m": None, "yaw_max_deg": None,
         "yaw_final_deg": None, "rotation_max_deg": None},
    ],
}  # fmt: skip


@pytest.fixture(scope="module")
def experiment(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = write_experiment(tmp_path_factory.mktemp("answer-exp"))
    (root / "analysis.json").write_text(
        json.dumps(_analysis({"force": [5.0, 10.0], "current": [0.0, 0.2]}))
    )
    (root / "sensitivity.json").write_text(json.dumps(SENSITIVITY))
    return root


@pytest.fixture(scope="module")
def thresholds(experiment: Path, tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, float]:
    """A rule on the vehicle's x MAE that only the current = 0.2 runs break (their lag is
    0.08 s against 0.02 s): the bound halfway between the two groups."""
    table = load_experiment_results(experiment).table
    x = table.select(topic=VEHICLE, axis="x", metric="mae")
    low = float(x.loc[x["current"] == 0.0, "value"].max())
    high = float(x.loc[x["current"] == 0.2, "value"].min())
    assert low < high
    bound = (low + high) / 2
    path = tmp_path_factory.mktemp("th") / "th.toml"
    path.write_text(
        f'[[threshold]]\nname = "vehicle x MAE"\nmetric = "mae"\naxes = ["x"]\n'
        f'topics = ["{VEHICLE}"]\nmax = {bound!r}\n'
    )
    return path, bound


@pytest.fixture(scope="module")
def built(
    experiment: Path, thresholds: tuple[Path, float], tmp_path_factory: pytest.TempPathFactory
) -> tuple[Path, Path, str]:
    out = tmp_path_factory.mktemp("answer-out")
    res = run_uwval(
        "report", experiment, "-o", out / "r.html", "--pdf", out / "r.pdf",
        "--thresholds", thresholds[0], "--max-detail-runs", "1",
    )  # fmt: skip
    assert res.returncode == 0, res.stdout + res.stderr
    # piped: one line per finished stage, then the summary line, none wrapped
    stages = [ln for ln in res.stdout.splitlines() if ln.startswith("report: ")]
    assert [ln.split(":")[1].strip() for ln in stages][-2:] == ["write HTML", "write PDF"]
    assert all(re.fullmatch(r"report: .+: \d+\.\d s \(total \d+\.\d s\)", ln) for ln in stages)
    assert re.search(
        r"wrote .*r\.html and .*r\.pdf \(8 run\(s\)\); verdict FAIL \(in \d+\.\d s\)", res.stdout
    )
    return out / "r.html", out / "r.pdf", (out / "r.html").read_text()


def test_number_formats_per_quantity() -> None:
    assert fmt(0.0090651, Quantity.LENGTH) == "9.07"  # m -> mm, 2 decimals
    assert fmt(5.971e-04, Quantity.LENGTH) == "0.60"
    assert fmt(0.12345, Quantity.ANGLE) == "0.123"
    assert fmt_correlation(0.99951) == "0.9995"
    # a saturated r never reads as a perfect 1
    assert fmt_correlation(0.999996) == "0.999996"
    assert fmt_correlation(1.0) == "1.0000"
    assert fmt_p(0.0312) == "0.031" and fmt_p(1e-17) == "1.0e-17"
    assert fmt(0.91, Quantity.FRACTION) == "91.0"
    assert fmt(0.0124, Quantity.DURATION) == "12.4"
    assert fmt(float("nan"), Quantity.LENGTH) == "n/a"
    assert fmt_correlation_interval(0.999991, 0.999996) == "[0.999991, 0.999996]"
    assert fmt_correlation_interval(0.95, 0.97) == "[0.9500, 0.9700]"


def test_the_answer_comes_first_in_html_and_on_pdf_page_1(built: tuple[Path, Path, str]) -> None:
    _, pdf, html = built
    header = html.split("<main>")[0]
    assert ANSWER.replace("'", "&#39;") in header  # before any section
    first = html.index('<section id="answer">')
    assert first == html.index("<section")
    assert html.count("Unity shows Gazebo&#39;s pose 12.4 ms late") == 1  # said once
    # effect sizes (partial eta^2 in %, p), per-level means with CIs (mm), the lag (ms)
    assert "current η² (η²p) %" in html
    assert ">91.3 (91.0)<" in html and ">3.2e-05<" in html  # eta^2 (partial eta^2)
    assert ">7.0<" in html  # a term without eta_sq: its partial eta^2 alone
    assert "force:current: 2.0 %" in html
    assert "3.10 [2.90, 3.30]" in html and "4.10 [3.90, 4.30]" in html
    assert ">12.4<" in html and "12.0 to 12.9" in html and ">98.0<" in html
    assert "Pearson r is saturated on x" in html
    # the one-way ANOVA is a secondary, collapsed view after the summary
    assert html.index('id="summary"') < html.index('id="one-way"')
    assert "<details>\n  <summary><h2>Secondary view: one factor at a time" in html
    if PDFTOTEXT:
        page1 = subprocess.run(
            [PDFTOTEXT, "-f", "1", "-l", "1", str(pdf), "-"], capture_output=True, text=True
        ).stdout
        assert "Unity shows Gazebo's pose 12.4 ms late" in " ".join(page1.split())


def test_sensitivity_is_a_table_and_a_diverged_variant_shows_no_number(
    built: tuple[Path, Path, str],
) -> None:
    _, _, html = built
    sec = html.split('<section id="sensitivity">')[1].split("</section>")[0]
    assert "coriolis: Coriolis entries of gz-sim 8.0-8.11" in sec  # the labels, listed
    row = sec.split('<td class="">coriolis</td>')[1].split("</tr>")[0]
    cells = re.findall(r"<td[^>]*>([^<]*)</td>", row)
    # what the variant changes, then mm, mm, deg x 3
    assert cells == ["coriolis legacy", "1.20", "1.10", "0.300", "0.250", "0.400"]
    div = sec.split('<td class="">added_mass</td>')[1].split("</tr>")[0]
    assert "diverged at 1.25 s" in div
    assert re.findall(r"<td[^>]*>([^<]*)</td>", div)[1:] == [
        "diverged at 1.25 s",
        *["n/a"] * 4,
    ]


def test_pass_fail_per_level_and_rule_with_the_bound(
    built: tuple[Path, Path, str], thresholds: tuple[Path, float], experiment: Path
) -> None:
    _, _, html = built
    _, bound = thresholds
    table = load_experiment_results(experiment).table
    x = table.select(topic=VEHICLE, axis="x", metric="mae")
    sec = html.split('<section id="verdict">')[1].split("</section>")[0]
    header = f"vehicle x MAE ≤ {bound * 1e3:.2f} mm"
    assert header in sec

    def cell(level: str) -> str:
        row = sec.split(f'<td class="">{level}</td>')[1].split("</tr>")[0]
        return re.findall(r"<td class=\"(\w*)\">([^<]*)</td>", row)[1]

    worst = {c: float(x.loc[x["current"] == c, "value"].max()) for c in (0.0, 0.2)}
    assert cell("current = 0.2 m/s") == ("bad", f"FAIL {worst[0.2] * 1e3:.2f}")
    assert cell("current = 0 m/s") == ("good", f"PASS {worst[0.0] * 1e3:.2f}")
    # both force levels hold current = 0.2 runs: both fail
    assert cell("force = 5 N")[0] == "bad" and cell("force = 10 N")[0] == "bad"
    assert cell("all runs") == ("bad", f"FAIL {x['value'].max() * 1e3:.2f}")
    # the page head says where it fails, in a sentence
    head = html.split("<main>")[0]
    assert "vehicle x MAE fails only at current = 0.2 m/s (worst " in head
    assert f"{worst[0.2] * 1e3:.2f} of ≤ {bound * 1e3:.2f} mm)" in head
    # the rules table: the bound as a number, the worst value, FAIL
    rules = sec.split("Threshold rules")[1].split("</table>")[0]
    assert f"≤ {bound * 1e3:.2f} mm" in rules and ">FAIL<" in rules
    # the bound is drawn on the MAE-per-level figure (a legend entry names it)
    assert 'alt="MAE per level: model_rov_pose"' in html


def test_one_number_format_in_the_tables(built: tuple[Path, Path, str]) -> None:
    _, _, html = built
    body = html.split("<main>")[1]
    for sec_id in ("paper", "summary", "runs", "verdict"):
        sec = body.split(f'<section id="{sec_id}">')[1].split("</section>")[0]
        cells = re.findall(r"<td[^>]*>([^<]*)</td>", sec)
        sci = [c for c in cells if re.search(r"\d\.?\d*e[-+]\d", c)]
        assert not sci, (sec_id, sci[:5])  # 0.009065 never beside 5.971e-04 again
    paper = body.split('<section id="paper">')[1].split("</table>")[0]
    triples = re.findall(r"<td[^>]*>(\d+\.\d+ / \d+\.\d+ / \d+\.\d+)</td>", paper)
    assert triples and all(
        all(len(v.split(".")[1]) in (2, 3) for v in t.split(" / ")) for t in triples
    )


def test_the_method_is_stated_on_every_page(built: tuple[Path, Path, str]) -> None:
    _, pdf, html = built
    line = "Method: sync interp (Unity interpolated onto the Gazebo stamps); clock offset 0.0 ms"
    assert html.count(line) == 2  # under the title and in the footer
    if not PDFTOTEXT:
        return
    pages = subprocess.run([PDFTOTEXT, str(pdf), "-"], capture_output=True, text=True).stdout
    pages_list = [" ".join(p.split()) for p in pages.split("\f") if p.strip()]
    assert len(pages_list) > 5
    for i, p in enumerate(pages_list):
        assert "Method: sync interp" in p, f"page {i + 1} does not say its method"


def test_absent_or_damaged_study_files_are_said(tmp_path: Path) -> None:
    root = write_experiment(tmp_path / "e", reps=1)
    out = build_report(root, tmp_path / "a.html", max_detail_runs=0)
    html = out.html.read_text()
    assert "No analysis.json beside these results" in html
    assert "No sensitivity.json beside these results" in html
    (root / "analysis.json").write_text('{"schema": "uwval.analysis/1", "topics": {')
    (root / "sensitivity.json").write_text(json.dumps({"schema": "something-else/9"}))
    html = build_report(root, tmp_path / "b.html", max_detail_runs=0).html.read_text()
    assert f"{root / 'analysis.json'}: not valid JSON (line 1, column 43): not shown" in html
    assert "schema &#39;something-else/9&#39;, expected &#39;uwval-sensitivity/1&#39;" in html


@pytest.mark.skipif(CHROMIUM is None, reason="chromium not installed (.ci/run installs it)")
def test_every_table_fits_1400_px_in_chromium(
    built: tuple[Path, Path, str], tmp_path: Path
) -> None:
    page, _, _ = built
    dt = DevTools(tmp_path / "profile")
    try:
        dt.call(
            "Emulation.setDeviceMetricsOverride",
            {"width": 1400, "height": 1000, "deviceScaleFactor": 1, "mobile": False},
        )
        dt.call("Page.navigate", {"url": page.as_uri()})
        dt.wait_event("Page.loadEventFired")
        dt.js("document.querySelectorAll('details').forEach(d => d.open = true)")
        overflow = dt.js(
            "[...document.querySelectorAll('.table-wrap')]"
            ".filter(w => w.scrollWidth > w.clientWidth + 1)"
            ".map(w => w.querySelector('caption').textContent + ' ' + w.scrollWidth + '>' + "
            "w.clientWidth)"
        )
        n_tables = dt.js("document.querySelectorAll('.table-wrap').length")
    finally:
        dt.close()
    assert n_tables > 10
    assert overflow == []  # no table hides a column behind a scroll bar


@pytest.mark.skipif(PDFTOTEXT is None, reason="pdftotext not installed (poppler-utils)")
def test_no_pdf_table_is_split_into_column_groups(built: tuple[Path, Path, str]) -> None:
    _, pdf, _ = built
    text = subprocess.run([PDFTOTEXT, str(pdf), "-"], capture_output=True, text=True).stdout
    assert "(columns 1 of" not in text  # every table fits the A4 width whole


def test_compare_html_states_its_method(tmp_path: Path) -> None:
    from results_logs import write_pair_log

    log = write_pair_log(tmp_path / "run.mcap", lag_s=0.02)
    page = tmp_path / "page.html"
    res = run_uwval("compare", log, "--html", page, "--sync", "nearest", "--max-diff", "0.01")
    assert res.returncode == 0, res.stdout + res.stderr
    html = page.read_text()
    assert '<p class="method">Method: sync nearest stamp (max dt 10.0 ms); clock offset' in html
    assert "alignment none; errors in ENU" in html


def test_compare_html_table_uses_the_report_number_format(tmp_path: Path) -> None:
    from results_logs import write_pair_log

    log = write_pair_log(tmp_path / "run.mcap", lag_s=0.02, noise=0.001)
    page = tmp_path / "page.html"
    assert run_uwval("compare", log, "--html", page).returncode == 0
    doc = json.loads(run_uwval("compare", log, "--json").stdout)
    html = page.read_text()
    table = html.split("<tbody>")[1].split("</tbody>")[0]
    cells = re.findall(r"<td>([^<]*)</td>", table)
    assert not [c for c in cells if "e-" in c]
    x = doc["axes"]["x"]
    assert f"<td>x</td><td>mm</td><td>{x['mae'] * 1e3:.2f}</td>" in table
