"""The gate refuses to pass what it did not check (issue 32.6) and finds its embedded
defaults by name from any folder (issue 33.1/5): end to end through ``uwval check``."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pandas as pd
import pytest
from cli_runner import run_uwval
from results_logs import VEHICLE, write_experiment, write_pair_log

from uwval.gate import GateInputError, check, missing_integrity, require_integrity
from uwval.resources import data_dir
from uwval.results import ResultsTable, load_experiment_results


@pytest.fixture(scope="module")
def experiment(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_experiment(tmp_path_factory.mktemp("trust-exp"), reps=1)


def _regressed(experiment: Path, dest: Path, factor: float) -> Path:
    """A copy of ``experiment`` whose first run's MAE/RMSE/max/p95 are ``factor`` x larger."""
    shutil.copytree(experiment, dest)
    path = dest / "results" / "comparisons.json"
    doc = json.loads(path.read_text())
    comp = doc["runs"][0]["comparison"]
    for sect in [comp, *comp["topics"].values()]:
        for axis in sect["axes"].values():
            for k in ("mae", "rmse", "max", "p95"):
                axis[k] *= factor
    path.write_text(json.dumps(doc))
    return dest


def test_a_baseline_of_pearson_r_alone_fails_a_regressed_mae(
    experiment: Path, tmp_path: Path
) -> None:
    golden = tmp_path / "golden.json"
    wrote = run_uwval("check", experiment, "--write-baseline", golden)
    assert wrote.returncode == 0, wrote.stdout + wrote.stderr
    doc = json.loads(golden.read_text())
    doc["rows"] = [r for r in doc["rows"] if r["metric"] == "pearson_r"]
    r_only = tmp_path / "r_only.json"
    r_only.write_text(json.dumps(doc))
    worse = _regressed(experiment, tmp_path / "worse", 10.0)
    res = run_uwval("check", worse, "--baseline", r_only)
    # used to print "PASS (n values checked)": r did not move, the MAE grew tenfold
    assert res.returncode == 1, res.stdout + res.stderr
    assert "FAIL" in res.stdout
    for metric in ("mae", "rmse", "max", "p95"):
        assert f"{metric}: not checked against the baseline: the baseline holds no {metric}" in (
            res.stdout
        )
    # the full baseline catches the regression itself, and passes the unchanged results
    assert run_uwval("check", experiment, "--baseline", golden).returncode == 0
    full = run_uwval("check", worse, "--baseline", golden)
    assert full.returncode == 1
    assert "mae run=" in full.stdout


def test_a_baseline_lacking_a_metric_for_some_values_names_them(experiment: Path) -> None:
    table = load_experiment_results(experiment).table
    gated = table.df[table.df["metric"].isin(["mae", "rmse", "max", "p95", "pearson_r"])]
    gone = (gated["metric"] == "mae") & (gated["axis"] == "yaw")
    base = ResultsTable.from_dataframe(gated[~gone], table.factors)
    verdict = check(table, baseline=base)
    assert not verdict.passed
    (v,) = verdict.violations
    assert (v.kind.value, v.metric) == ("uncovered", "mae")
    n_keys = gated[gated["metric"] == "mae"][["run", "topic", "axis"]].drop_duplicates()
    n_yaw = int((n_keys["axis"] == "yaw").sum())
    assert f"lacks mae for {n_yaw} of {len(n_keys)}" in v.describe()


def _strip(comp: dict[str, object], field: str) -> None:
    for sect in [comp, *comp["topics"].values()]:  # type: ignore[attr-defined]
        for src in ("reference", "other"):
            sect[src].pop(field, None)  # type: ignore[index]


@pytest.mark.parametrize("field", ["dropped", "warnings"])
def test_a_saved_compare_json_without_integrity_fields_is_refused(
    tmp_path: Path, field: str
) -> None:
    log = write_pair_log(tmp_path / "run.mcap", lag_s=0.02)
    saved = tmp_path / "saved.json"
    made = run_uwval("compare", log, "-o", saved)
    assert made.returncode == 0, made.stdout + made.stderr
    ok = run_uwval("check", saved, "--thresholds", "default")
    assert ok.returncode in (0, 1), ok.stdout + ok.stderr  # gated, not refused
    doc = json.loads(saved.read_text())
    assert missing_integrity(doc) == []
    _strip(doc, field)
    assert f"topics.{VEHICLE}.other.{field}" in missing_integrity(doc)
    saved.write_text(json.dumps(doc))
    res = run_uwval("check", saved, "--thresholds", "default")
    assert res.returncode == 2, res.stdout + res.stderr
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1, res.stderr
    assert str(saved) in lines[0]
    assert f"other.{field}" in lines[0]
    assert "Traceback" not in res.stderr
    assert "PASS" not in res.stdout


def test_an_experiment_and_a_table_without_integrity_fields_are_refused(
    experiment: Path, tmp_path: Path
) -> None:
    exp = tmp_path / "exp"
    shutil.copytree(experiment, exp)
    comp_path = exp / "results" / "comparisons.json"
    doc = json.loads(comp_path.read_text())
    _strip(doc["runs"][1]["comparison"], "dropped")
    comp_path.write_text(json.dumps(doc))
    res = run_uwval("check", exp, "--thresholds", "default")
    assert res.returncode == 2, res.stdout + res.stderr
    assert str(exp) in res.stderr and doc["runs"][1]["name"] in res.stderr
    # a results table keeps the readers' warnings as n_warnings rows: without them, refused
    table = load_experiment_results(experiment).table
    df = table.df[table.df["metric"] != "n_warnings"]
    (csv,) = ResultsTable.from_dataframe(df, table.factors).save(tmp_path / "results.csv")
    res = run_uwval("check", csv, "--thresholds", "default")
    assert res.returncode == 2, res.stdout + res.stderr
    assert "results.csv: refused" in res.stderr
    # the intact table passes the check of its integrity
    require_integrity(table, [(r, None) for r in table.runs], "t.csv")
    with pytest.raises(GateInputError, match="n_warnings"):
        require_integrity(ResultsTable.from_dataframe(df, table.factors), [], "t.csv")


def test_default_thresholds_and_baseline_from_an_empty_folder(
    experiment: Path, tmp_path: Path
) -> None:
    empty = tmp_path / "elsewhere"
    empty.mkdir()
    th = run_uwval("check", experiment, "--thresholds", "default", cwd=empty)
    assert th.returncode in (0, 1), th.stdout + th.stderr
    assert "values checked" in th.stdout.splitlines()[0]
    # the embedded baseline is the default experiment's: these runs are not in it, so it
    # fails (naming them), but it is found and read, not refused
    base = run_uwval("check", experiment, "--baseline", "default", cwd=empty)
    assert base.returncode == 1, base.stdout + base.stderr
    assert "not covered by the baseline" in base.stdout
    assert "no such" not in base.stderr


def test_check_output_is_not_wrapped_when_piped(experiment: Path, tmp_path: Path) -> None:
    th = tmp_path / "tight.toml"
    th.write_text(
        '[[threshold]]\nname = "a rule with a rather long name to make long lines"\n'
        'metric = "mae"\naxes = ["x"]\nmax = 1e-9\n'
    )
    res = run_uwval("check", experiment, "--thresholds", th)
    assert res.returncode == 1
    lines = res.stdout.splitlines()
    assert lines[0].startswith("uwval check: FAIL")
    body = [ln for ln in lines if ln.startswith("  - mae run=")]
    assert body and all("must be <= 1e-09 m [a rule with a rather long name" in ln for ln in body)
    assert max(len(ln) for ln in body) > 100  # one line per violation, however long


def test_the_report_names_embedded_defaults_without_their_install_path(
    experiment: Path, tmp_path: Path
) -> None:
    out = tmp_path / "r.html"
    res = run_uwval(
        "report", experiment, "-o", out, "--thresholds", "default", "--baseline", "default"
    )
    assert res.returncode == 0, res.stdout + res.stderr
    html = out.read_text()
    root = str(data_dir())
    assert root not in html and root not in res.stdout
    assert "default (embedded: thresholds/default.toml)" in html
    assert "default (embedded: baselines/default.json)" in html


def test_results_table_without_warning_rows_reads_as_a_gap() -> None:
    df = pd.DataFrame(
        {
            "run": ["a"],
            "topic": ["t"],
            "axis": ["x"],
            "metric": ["mae"],
            "value": [0.1],
            "unit": ["m"],
            "note": [""],
        }
    )
    with pytest.raises(GateInputError, match=r"a/t \(reference.n_warnings and other"):
        require_integrity(ResultsTable.from_dataframe(df, []), [], "x.csv")


def test_the_report_shows_refused_results_as_refused(experiment: Path, tmp_path: Path) -> None:
    exp = tmp_path / "exp"
    shutil.copytree(experiment, exp)
    comp_path = exp / "results" / "comparisons.json"
    doc = json.loads(comp_path.read_text())
    _strip(doc["runs"][0]["comparison"], "warnings")
    comp_path.write_text(json.dumps(doc))
    out = tmp_path / "r.html"
    res = run_uwval("report", exp, "-o", out, "--max-detail-runs", "0")
    assert res.returncode == 0, res.stdout + res.stderr  # the report is written...
    assert "verdict REFUSED" in res.stdout  # ...but the gate passes nothing
    html = out.read_text()
    assert 'class="verdict-badge fail">REFUSED<' in html
    assert "other.warnings" in html and "PASS" not in html.split("<main>")[0]
