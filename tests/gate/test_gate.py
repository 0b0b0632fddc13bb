"""The CI gate: thresholds TOML, golden baselines, `uwval check` exit codes, pytest plugin."""

from __future__ import annotations

import json
import math
import re
import subprocess
import sys
import textwrap
from pathlib import Path

import pandas as pd
import pytest
from cli_runner import run_uwval as _uwval
from hypothesis import given, settings
from hypothesis import strategies as st

from uwval.errors import ConfigError
from uwval.gate import (
    BaselineTolerance,
    check,
    check_baseline,
    load_thresholds,
    parse_thresholds,
)
from uwval.results import ResultsTable, load_experiment_results

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from results_logs import VEHICLE, write_experiment, write_pair_log

REPO = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def experiment(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_experiment(tmp_path_factory.mktemp("gate-exp"))


@pytest.fixture(scope="module")
def table(experiment: Path) -> ResultsTable:
    return load_experiment_results(experiment).table


def _toml(tmp_path: Path, text: str, name: str = "th.toml") -> Path:
    p = tmp_path / name
    p.write_text(textwrap.dedent(text))
    return p


def _x_mae(table: ResultsTable, run: str) -> float:
    return table.value(run, VEHICLE, "x", "mae")


# ----------------------------------------------------------------------------- thresholds
def test_threshold_violation_lists_metric_topic_axis_levels_value_bound(
    table: ResultsTable, tmp_path: Path
) -> None:
    ranked = sorted(table.runs, key=lambda r: _x_mae(table, r))
    worst_run = ranked[-1]
    worst = _x_mae(table, worst_run)
    bound = (worst + _x_mae(table, ranked[-2])) / 2  # only the worst run breaks it
    th = load_thresholds(
        _toml(
            tmp_path,
            f"""
        [[threshold]]
        metric = "mae"
        axes = ["x"]
        topics = ["{VEHICLE}"]
        max = {bound!r}
    """,
        )
    )
    verdict = check(table, th)
    assert not verdict.passed
    assert len(verdict.violations) == 1
    v = verdict.violations[0]
    assert (v.metric, v.topic, v.axis, v.run) == ("mae", VEHICLE, "x", worst_run)
    assert v.value == worst
    assert v.bound == bound
    assert v.op == "<="
    assert v.factors == {"force": 10.0, "torque": 0.0, "current": 0.2}
    text = verdict.format()
    assert "FAIL - 1 regression" in text
    assert f"run={worst_run}" in text
    assert "axis=x" in text
    assert "current=0.2" in text
    assert f"must be <= {bound:.6g} m" in text
    assert verdict.checked == len(table.runs)


def test_min_bound_factor_filter_and_undefined_policy(table: ResultsTable) -> None:
    # Pearson r of x is > 0.999 everywhere; z is constant (r undefined)
    ok = check(
        table,
        parse_thresholds({"threshold": [{"metric": "pearson_r", "axes": ["x", "z"], "min": 0.99}]}),
    )
    assert ok.passed
    assert ok.checked == 2 * 2 * len(table.runs)
    assert len(ok.skipped) == 2 * len(table.runs)  # both topics' z, skipped with the reason
    assert "constant" in ok.skipped[0]
    strict = check(
        table,
        parse_thresholds(
            {
                "threshold": [
                    {"metric": "pearson_r", "axes": ["z"], "min": 0.99, "undefined": "fail"}
                ]
            }
        ),
    )
    assert {v.kind for v in strict.violations} == {"undefined"}
    assert len(strict.violations) == 2 * len(table.runs)
    # a bound that only the current = 0.2 runs break, restricted to current = 0 -> pass
    lo = max(_x_mae(table, r) for r in table.runs if "current0_" in r)
    only0 = parse_thresholds(
        {
            "threshold": [
                {
                    "metric": "mae",
                    "axes": "x",
                    "max": lo,
                    "topics": VEHICLE,
                    "factors": {"current": 0.0},
                }
            ]
        }
    )
    assert check(table, only0).passed
    everywhere = parse_thresholds(
        {"threshold": [{"metric": "mae", "axes": "x", "max": lo, "topics": VEHICLE}]}
    )
    bad = check(table, everywhere)
    assert not bad.passed
    assert all(v.factors["current"] == 0.2 for v in bad.violations)


def test_a_rule_matching_nothing_fails(table: ResultsTable) -> None:
    verdict = check(table, parse_thresholds({"threshold": [{"metric": "mea", "max": 1.0}]}))  # typo
    assert not verdict.passed
    assert verdict.violations[0].kind == "no-match"
    assert "matched no results" in verdict.format()
    with pytest.raises(ConfigError, match="filters on factor 'speed'"):
        check(
            table,
            parse_thresholds(
                {"threshold": [{"metric": "mae", "max": 1.0, "factors": {"speed": 1}}]}
            ),
        )


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("[[threshold]]\nmetric = 'mae'\n", "give 'max' and/or 'min'"),
        ("[[threshold]]\nmax = 1\n", "'metric' .* is required"),
        ("[[threshold]]\nmetric = 'mae'\nmax = 'big'\n", "'max' must be a number"),
        ("[[threshold]]\nmetric = 'mae'\nmax = 1\nbogus = 2\n", r"unknown key\(s\) \['bogus'\]"),
        ("[[threshold]]\nmetric = 'mae'\nmax = 1\nundefined = 'maybe'\n", "'undefined' must be"),
        ("version = 2\n", "unsupported thresholds version 2"),
        ("threshold = 3\n", "must be an array of tables"),
        ("[baseline]\nrtol = -1\n", "rtol must be a number >= 0"),
        ("[[threshold]\n", "not valid TOML"),
        ("colour = 1\n", r"unknown top-level key\(s\) \['colour'\]"),
        # a NaN bound compares false both ways and would pass everything
        ("[[threshold]]\nmetric = 'mae'\nmax = nan\n", "'max' must be a finite number"),
        ("[[threshold]]\nmetric = 'mae'\nmin = -inf\n", "'min' must be a finite number"),
        ("[[threshold]]\nmetric = 'mae'\nmin = 2\nmax = 1\n", "'min' 2 is above 'max' 1"),
    ],
)
def test_bad_thresholds_name_the_file_and_rule(tmp_path: Path, text: str, message: str) -> None:
    p = _toml(tmp_path, text, "ci-thresholds.toml")
    with pytest.raises(ConfigError, match=message) as info:
        load_thresholds(p)
    assert "ci-thresholds.toml" in str(info.value)


def test_embedded_default_thresholds_parse() -> None:
    th = load_thresholds(REPO / "data" / "thresholds" / "default.toml")
    assert th.rules
    assert {r.metric for r in th.rules} >= {"mae", "max", "pearson_r"}
    assert th.baseline.rtol > 0


# ----------------------------------------------------------------------------- baseline
def test_baseline_identical_passes_and_regression_is_caught(
    table: ResultsTable, tmp_path: Path
) -> None:
    (golden,) = table.save(tmp_path / "golden.json")
    same = check(table, baseline=golden)
    assert same.passed
    assert same.checked > 0
    df = table.to_dataframe()
    run = table.runs[3]
    hit = (df["run"] == run) & (df["topic"] == VEHICLE) & (df["axis"] == "yaw")
    df.loc[hit & (df["metric"] == "mae"), "value"] *= 2.0
    df.loc[hit & (df["metric"] == "pearson_r"), "value"] = 0.5
    worse = ResultsTable.from_dataframe(df, table.factors)
    verdict = check(worse, baseline=golden)
    got = {(v.metric, v.run, v.topic, v.axis) for v in verdict.violations}
    assert got == {("mae", run, VEHICLE, "yaw"), ("pearson_r", run, VEHICLE, "yaw")}
    mae = next(v for v in verdict.violations if v.metric == "mae")
    base = table.value(run, VEHICLE, "yaw", "mae")
    tol = BaselineTolerance()
    assert mae.bound == pytest.approx(base * (1 + tol.rtol) + tol.atol_deg)
    assert mae.value == pytest.approx(2 * base)
    r = next(v for v in verdict.violations if v.metric == "pearson_r")
    assert r.bound == pytest.approx(table.value(run, VEHICLE, "yaw", "pearson_r") - tol.atol_r)
    # improvements never fail: zero MAE everywhere breaks no MAE bound
    better = df.copy()
    better.loc[better["metric"] == "mae", "value"] = 0.0
    improved = check(ResultsTable.from_dataframe(better, table.factors), baseline=golden)
    assert not [v for v in improved.violations if v.metric == "mae"]


def test_missing_run_in_results_fails(table: ResultsTable) -> None:
    part = ResultsTable.from_dataframe(table.df[table.df["run"] != table.runs[0]], table.factors)
    verdict = check_baseline(part, table)
    assert verdict.violations
    # the whole run is absent: one failure naming it, not one per value
    assert {v.kind for v in verdict.violations} == {"missing-run"}
    assert [v.run for v in verdict.violations] == [table.runs[0]]
    assert {v.run for v in verdict.violations} == {table.runs[0]}
    assert "missing from the results" in verdict.format()


def test_check_needs_something_to_check(table: ResultsTable) -> None:
    with pytest.raises(ConfigError, match="needs --thresholds"):
        check(table)


# ----------------------------------------------------------------------------- CLI


def test_cli_check_exit_codes(experiment: Path, table: ResultsTable, tmp_path: Path) -> None:
    loose = _toml(
        tmp_path,
        """
        [[threshold]]
        metric = "mae"
        axes = ["x", "y", "z"]
        max = 1.0
    """,
        "loose.toml",
    )
    ok = _uwval("check", str(experiment), "--thresholds", str(loose))
    assert ok.returncode == 0, ok.stderr
    assert "PASS" in ok.stdout
    tight = _toml(
        tmp_path,
        """
        [[threshold]]
        name = "vehicle x MAE"
        metric = "mae"
        axes = "x"
        topics = "model_rov_pose"
        max = 1e-6
    """,
        "tight.toml",
    )
    bad = _uwval("check", str(experiment / "results"), "--thresholds", str(tight))
    assert bad.returncode == 1
    # the verdict is the command's output: stdout, FAIL as PASS
    assert f"FAIL - {len(table.runs)} regression(s)" in bad.stdout
    assert "[vehicle x MAE]" in bad.stdout
    assert "must be <= 1e-06 m" in bad.stdout
    js = _uwval("check", str(experiment), "--thresholds", str(tight), "--json")
    assert js.returncode == 1
    obj = json.loads(js.stdout)
    assert obj["passed"] is False
    assert len(obj["violations"]) == len(table.runs)
    assert {"metric", "topic", "axis", "factors", "value", "bound"} <= set(obj["violations"][0])
    # exit 2: unreadable input, one line naming the file
    broken = _toml(tmp_path, "[[threshold]\n", "broken.toml")
    err = _uwval("check", str(experiment), "--thresholds", str(broken))
    assert err.returncode == 2
    assert "broken.toml" in err.stderr
    assert "Traceback" not in err.stderr
    none = _uwval("check", str(experiment))
    assert none.returncode == 2
    assert "needs --thresholds" in none.stderr


def test_cli_check_against_baseline(experiment: Path, table: ResultsTable, tmp_path: Path) -> None:
    (golden,) = table.save(tmp_path / "golden.csv")
    assert _uwval("check", str(experiment), "--baseline", str(golden)).returncode == 0
    df = pd.read_csv(golden, keep_default_na=False, na_values=[""])
    df.loc[df["metric"] == "max", "value"] = df.loc[df["metric"] == "max", "value"] / 10
    df.to_csv(golden, index=False)
    res = _uwval("check", str(experiment), "--baseline", str(golden))
    assert res.returncode == 1
    assert "max run=" in res.stdout


# ----------------------------------------------------------------------------- pytest plugin
def test_pytest_plugin_pattern_passes_and_fails(experiment: Path, tmp_path: Path) -> None:
    """The documented drop-in pattern, run in a separate pytest session."""
    log = write_pair_log(tmp_path / "rig.mcap", lag_s=0.02)
    _toml(
        tmp_path,
        """
        [[threshold]]
        metric = "mae"
        axes = ["x", "y", "z"]
        max = 0.1
    """,
        "ci.toml",
    )
    (tmp_path / "conftest.py").write_text('pytest_plugins = ["uwval.pytest_plugin"]\n')
    (tmp_path / "test_rig.py").write_text(
        textwrap.dedent(f"""
        from uwval.pytest_plugin import assert_pose_correspondence

        def test_log_passes():
            v = assert_pose_correspondence({str(log)!r}, "ci.toml")
            assert v.passed and v.checked == 6  # 2 topics x 3 axes

        def test_fixture_uses_ini(uwval_check):
            uwval_check({str(experiment)!r})

        def test_fixture_reports_regressions(uwval_check):
            uwval_check({str(log)!r}, {{"threshold": [
                {{"metric": "mae", "axes": ["x"], "max": 1e-9}}]}})
    """)
    )
    (tmp_path / "pytest.ini").write_text("[pytest]\nuwval_thresholds = ci.toml\n")
    res = subprocess.run(
        [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "test_rig.py"],
        capture_output=True,
        text=True,
        cwd=tmp_path,
        timeout=120,
    )
    out = res.stdout + res.stderr
    assert res.returncode == 1, out
    assert "2 passed" in out
    assert "1 failed" in out
    assert "test_fixture_reports_regressions" in out
    assert "mae run=rig topic=model_rov_pose axis=x" in out
    assert "must be <= 1e-09 m" in out
    # --uwval-thresholds typed in a subdirectory is relative to that directory
    sub = tmp_path / "sub"
    sub.mkdir()
    (sub / "test_opt.py").write_text(
        textwrap.dedent(f"""
        def test_option_path(uwval_check):
            v = uwval_check({str(log)!r})
            assert v.checked == 6
    """)
    )
    res = subprocess.run(
        [
            sys.executable,
            "-m",
            "pytest",
            "-q",
            "-p",
            "no:cacheprovider",
            "--uwval-thresholds",
            "../ci.toml",
            "test_opt.py",
        ],
        capture_output=True,
        text=True,
        cwd=sub,
        timeout=120,
    )
    assert res.returncode == 0, res.stdout + res.stderr


def test_noise_level_correlation_in_the_baseline_is_not_gated(table: ResultsTable) -> None:
    df = table.to_dataframe()
    z_r = (df["axis"] == "yaw") & (df["metric"] == "pearson_r")
    noisy = df.copy()
    noisy.loc[z_r, "value"] = 0.13  # a baseline axis whose r is noise
    base = ResultsTable.from_dataframe(noisy, table.factors)
    now = df.copy()
    now.loc[z_r, "value"] = -0.2
    verdict = check_baseline(ResultsTable.from_dataframe(now, table.factors), base)
    assert verdict.passed
    assert any("r_min" in s for s in verdict.skipped)
    strict = check_baseline(
        ResultsTable.from_dataframe(now, table.factors), base, BaselineTolerance(r_min=-1.0)
    )
    assert not strict.passed


# ----------------------------------------------------------------------------- project CI
def test_default_experiment_passes_the_projects_own_gate(tmp_path: Path) -> None:
    """The project's CI gate: simulate the embedded default experiment (54 runs through the
    simulator, the TCP bridge and the recorder), compare, and check it against the embedded
    thresholds and the golden baseline (regenerate it with
    ``uwval simulate data/experiments/default.toml -o DIR && uwval check DIR
    --write-baseline data/baselines/default.json``)."""
    out = tmp_path / "default"
    sim = _uwval("simulate", str(REPO / "data" / "experiments" / "default.toml"), "-o", str(out))
    assert sim.returncode == 0, sim.stderr[-3000:]
    res = _uwval(
        "check",
        str(out),
        "--thresholds",
        str(REPO / "data" / "thresholds" / "default.toml"),
        "--baseline",
        str(REPO / "data" / "baselines" / "default.json"),
    )
    assert res.returncode == 0, res.stdout + res.stderr
    assert "PASS" in res.stdout


def test_a_rule_file_with_no_rules_is_not_a_pass(table: ResultsTable, tmp_path: Path) -> None:
    empty = _toml(tmp_path, "# nothing here yet\nversion = 1\n", "empty.toml")
    with pytest.raises(ConfigError, match=r"empty\.toml: defines no threshold rules"):
        check(table, empty)
    golden = tmp_path / "golden.json"
    table.save(golden)
    assert check(table, empty, golden).passed  # with a baseline it only sets tolerances


def test_cli_check_bad_inputs_one_line_exit_2(experiment: Path, tmp_path: Path) -> None:
    th = REPO / "data" / "thresholds" / "default.toml"
    junk = tmp_path / "r.parquet"
    junk.write_bytes(b"PAR1 not really")
    words = tmp_path / "words.csv"
    words.write_text("run,topic,axis,metric,value,unit,note\nr1,t,x,mae,abc,m,\n")
    cases = [
        (["check", str(junk), "--thresholds", str(th)], r"r\.parquet: not a readable Parquet"),
        (
            ["check", str(words), "--thresholds", str(th)],
            r"words\.csv: row 1 \(r1 t x mae\): value 'abc' is not a number",
        ),
        (["check", str(experiment), "--thresholds", str(tmp_path)], "is a directory"),
        (["check", str(experiment), "--baseline", str(tmp_path)], "is a directory"),
    ]
    for args, message in cases:
        proc = subprocess.run(
            [sys.executable, "-m", "uwval", *args], capture_output=True, text=True, timeout=120
        )
        assert proc.returncode == 2, (args, proc.stdout, proc.stderr)
        assert "Traceback" not in proc.stderr
        lines = proc.stderr.strip().splitlines()
        assert len(lines) == 1, proc.stderr
        assert re.search(message, lines[0]), lines[0]


# ------------------------------------------------------ issue 14: what the gate must not pass
_MAE_RULE = {"threshold": [{"metric": "mae", "axes": ["x", "y", "z"], "max": 1.0}]}


def _with(table: ResultsTable, metric: str, value: float, note: str = "") -> ResultsTable:
    df = table.df.copy()
    sel = df["metric"] == metric
    df.loc[sel, "value"] = value
    df.loc[sel, "note"] = note
    return ResultsTable.from_dataframe(df, table.factors)


def test_nan_error_metrics_fail_instead_of_being_skipped(
    table: ResultsTable, tmp_path: Path
) -> None:
    # every MAE and max NaN used to print "PASS (... undefined value(s) skipped)"
    broken = _with(_with(table, "mae", math.nan), "max", math.nan)
    rules = {"threshold": [*_MAE_RULE["threshold"], {"metric": "max", "max": 5.0}]}
    verdict = check(broken, parse_thresholds(rules))
    assert not verdict.passed
    assert {v.kind for v in verdict.violations} == {"undefined"}
    assert not verdict.skipped
    # undefined = "skip" covers only what the engine leaves undefined on purpose
    skip = {"threshold": [{"metric": "mae", "max": 1.0, "undefined": "skip"}]}
    assert not check(broken, parse_thresholds(skip)).passed
    # the command line: exit 1 with the reason
    broken.save(tmp_path / "results.csv")
    th = _toml(tmp_path, '[[threshold]]\nmetric = "mae"\nmax = 1.0\n')
    res = _uwval("check", tmp_path / "results.csv", "--thresholds", th)
    assert res.returncode == 1, res.stdout + res.stderr
    assert "undefined (NaN)" in res.stdout


def test_a_missing_gated_value_in_the_compare_json_fails(table: ResultsTable) -> None:
    from uwval.results import MISSING_NOTE

    holed = _with(table, "mae", math.nan, MISSING_NOTE)
    verdict = check(holed, parse_thresholds(_MAE_RULE))
    assert {v.kind for v in verdict.violations} == {"undefined"}
    assert MISSING_NOTE in verdict.format()


def test_pearson_r_of_a_constant_series_may_be_undefined_with_its_reason(
    table: ResultsTable,
) -> None:
    # the engine's reason travels into the table and the skip line
    z = table.select(metric="pearson_r", axis="z")
    assert z["value"].isna().all()
    assert z["note"].str.contains("constant").all()
    rule = {"threshold": [{"metric": "pearson_r", "axes": ["z"], "min": 0.9}]}
    verdict = check(table, parse_thresholds(rule))
    assert verdict.passed
    assert all("constant" in s for s in verdict.skipped)
    # the same NaN without the engine's reason is not undefined by definition: it fails
    stripped = _with(table, "pearson_r", math.nan)
    assert not check(stripped, parse_thresholds(rule)).passed


def test_negative_mae_fails(table: ResultsTable) -> None:
    forged = _with(table, "mae", -0.5)
    verdict = check(forged, parse_thresholds(_MAE_RULE))
    assert not verdict.passed
    assert "invalid" in {v.kind for v in verdict.violations}
    assert "cannot be negative" in verdict.format()
    # against a baseline too (an error below the baseline would look like an improvement)
    assert not check(forged, baseline=table).passed


def test_impossible_correlation_fails(table: ResultsTable) -> None:
    verdict = check(_with(table, "pearson_r", 1.5), parse_thresholds(_MAE_RULE))
    assert "a correlation lies in [-1, 1]" in verdict.format()


def test_an_empty_baseline_is_refused(table: ResultsTable, tmp_path: Path) -> None:
    empty = tmp_path / "empty.json"
    empty.write_text(json.dumps({"format": "uwval-results", "version": 1, "rows": []}))
    with pytest.raises(ConfigError, match="no rows of the gated metrics"):
        check(table, baseline=empty)
    table.save(tmp_path / "results.csv")
    res = _uwval("check", tmp_path / "results.csv", "--baseline", empty)
    assert res.returncode == 2, res.stdout + res.stderr
    assert "cannot gate anything" in res.stderr
    assert "Traceback" not in res.stderr


def test_an_all_nan_baseline_is_refused(table: ResultsTable, tmp_path: Path) -> None:
    df = table.df.copy()
    df["value"] = math.nan
    nan_base = ResultsTable.from_dataframe(df, table.factors)
    with pytest.raises(ConfigError, match="NaN"):
        check(table, baseline=nan_base)
    # one NaN error metric in a baseline is refused too, naming the row
    one = table.df.copy()
    one.loc[one.index[(one["metric"] == "mae")][0], "value"] = math.nan
    with pytest.raises(ConfigError, match=r"baseline mae .* is NaN"):
        check(table, baseline=ResultsTable.from_dataframe(one, table.factors))
    nan_base.save(tmp_path / "base.json")
    table.save(tmp_path / "results.csv")
    res = _uwval("check", tmp_path / "results.csv", "--baseline", tmp_path / "base.json")
    assert res.returncode == 2, res.stdout + res.stderr


def test_a_baseline_covering_one_run_leaves_no_run_ungated(table: ResultsTable) -> None:
    first = table.runs[0]
    base = ResultsTable.from_dataframe(table.df[table.df["run"] == first], table.factors)
    # another run with MAE 5 m used to pass
    df = table.df.copy()
    df.loc[(df["run"] == table.runs[1]) & (df["metric"] == "mae"), "value"] = 5.0
    verdict = check(ResultsTable.from_dataframe(df, table.factors), baseline=base)
    assert not verdict.passed
    ungated = {v.run for v in verdict.violations if v.kind == "ungated"}
    assert ungated == set(table.runs[1:])
    assert "not covered by the baseline" in verdict.format()


def test_runs_of_the_manifest_missing_from_the_results_fail(
    experiment: Path, tmp_path: Path
) -> None:
    import shutil

    exp = tmp_path / "exp"
    shutil.copytree(experiment, exp)
    comp = json.loads((exp / "results" / "comparisons.json").read_text())
    dropped = comp["runs"].pop(0)["name"]
    (exp / "results" / "comparisons.json").write_text(json.dumps(comp))
    loaded = load_experiment_results(exp)
    assert dropped not in loaded.table.runs
    th = parse_thresholds(_MAE_RULE)
    verdict = check(loaded.table, th, expected_runs=[r.name for r in loaded.runs])
    assert [(v.kind, v.run) for v in verdict.violations] == [("missing-run", dropped)]
    th_file = _toml(tmp_path, '[[threshold]]\nmetric = "mae"\nmax = 1.0\n')
    res = _uwval("check", exp, "--thresholds", th_file)
    assert res.returncode == 1, res.stdout + res.stderr
    assert f"run={dropped}: the run is missing from the results" in res.stdout


def _warned_comparison(log: Path, warning: str, dropped: int) -> dict[str, object]:
    """A real comparison of ``log`` whose Unity stream carries a reader warning and drops."""
    from uwval import compare
    from uwval.comparison.logs import LogComparison
    from uwval.io import read_stream

    ref = read_stream(log, f"/gazebo/{VEHICLE}")
    uni = read_stream(log, f"/unity/{VEHICLE}")
    uni = uni.with_(warnings=(warning,), dropped={"truncated": dropped})
    return LogComparison({VEHICLE: compare(ref, uni)}, VEHICLE, [str(log)]).to_json()


def test_a_log_warning_travels_into_the_table_and_fails_the_gate(
    table: ResultsTable, tmp_path: Path
) -> None:
    log = write_pair_log(tmp_path / "cut.mcap", camera=False)
    text = "cut.mcap: not closed cleanly (no footer); 40 % of the bytes lost"
    obj = _warned_comparison(log, text, 7)
    # the compare JSON carries it at the top, per topic and per source
    assert text in obj["warnings"]  # type: ignore[operator]
    topic = obj["topics"][VEHICLE]  # type: ignore[index]
    assert topic["other"]["warnings"] == [text]
    assert topic["other"]["dropped"] == {"truncated": 7}
    warned = ResultsTable.from_comparisons([("cut", {}, obj)])
    row = warned.select(run="cut", axis="other", metric="n_warnings")
    assert float(row["value"].iloc[0]) == 1.0
    assert row["note"].iloc[0] == text
    assert warned.value("cut", VEHICLE, "other", "dropped.truncated") == 7.0
    # the table survives its files with the warning
    for suffix in (".csv", ".json"):
        warned.save(tmp_path / f"t{suffix}")
        again = ResultsTable.load(tmp_path / f"t{suffix}")
        assert again.select(axis="other", metric="n_warnings")["note"].iloc[0] == text
    # small errors, but the log was damaged: FAIL by default, with the reader's words
    th = parse_thresholds(_MAE_RULE)
    verdict = check(warned, th)
    assert not verdict.passed
    assert [v.kind for v in verdict.violations] == ["log-warning"]
    assert text in verdict.format()
    assert "7 message(s) dropped (truncated)" in verdict.format()
    # the thresholds may allow it: then it passes, and the warning is still shown
    allowed = parse_thresholds({**_MAE_RULE, "allow_log_warnings": True})
    ok = check(warned, allowed)
    assert ok.passed
    assert text in ok.format()
    with pytest.raises(ConfigError, match="allow_log_warnings"):
        parse_thresholds({**_MAE_RULE, "allow_log_warnings": "yes"})


def test_a_log_warning_reaches_the_command_line_gate_and_the_report(
    tmp_path: Path,
) -> None:
    log = write_pair_log(tmp_path / "cut.mcap", camera=False)
    text = "cut.mcap: not closed cleanly (no footer); 40 % of the bytes lost"
    comp = {
        "runs": [{"name": "cut", "factors": {}, "comparison": _warned_comparison(log, text, 3)}],
        "failed": [],
    }
    (tmp_path / "comparisons.json").write_text(json.dumps(comp))
    th = _toml(tmp_path, '[[threshold]]\nmetric = "mae"\nmax = 1.0\n')
    res = _uwval("check", tmp_path / "comparisons.json", "--thresholds", th)
    assert res.returncode == 1, res.stdout + res.stderr
    assert text in res.stdout
    exp = load_experiment_results(tmp_path / "comparisons.json")
    assert exp.run_warnings()["cut"][0] == text
    from uwval.reports.builder import build_report

    out = build_report(tmp_path / "comparisons.json", tmp_path / "r.html", thresholds=th)
    assert not out.gate.passed  # type: ignore[union-attr]
    assert text in (tmp_path / "r.html").read_text()


def test_check_on_a_manifest_with_one_bad_log_checks_the_rest(tmp_path: Path) -> None:
    from uwval.batch import Executor
    from uwval.bridge.experiment import SimulateOptions, run_experiment
    from uwval.resources import data_path

    m = run_experiment(  # a small sweep: 8 runs
        SimulateOptions(output=tmp_path / "exp", experiment="quick", executor=Executor.INLINE)
    ).manifest
    bad = m["runs"][2]
    (tmp_path / "exp" / bad["log"]).write_bytes(b"garbage")
    res = _uwval(
        "check", str(tmp_path / "exp"), "--thresholds", str(data_path("thresholds", "default.toml"))
    )
    assert res.returncode == 1, res.stdout + res.stderr
    assert "1 run(s) failed" in res.stderr
    assert bad["name"] in res.stderr
    assert "values checked" in res.stdout + res.stderr  # the other runs were gated


# ------------------------------------------------ looking for the next ones: a gate fuzzer
_AXES = ("x", "y", "z", "roll", "pitch", "yaw")
_FUZZ_KINDS = ("nan", "missing", "negative", "drop_run", "warning", "r_out", "inf")
_FUZZ_RULES = {
    "threshold": [
        {"metric": "mae", "max": 1e3},
        {"metric": "max", "max": 1e3},
        {"metric": "pearson_r", "axes": ["x"], "min": -1.0},
    ]
}


def _damage(table: ResultsTable, kind: str, pick: int) -> ResultsTable:
    """``table`` with one damage of ``kind`` at a place chosen by ``pick``."""
    df = table.df.copy()
    gated = df.index[df["metric"].isin(["mae", "max"]) & df["axis"].isin(list(_AXES))]
    row = gated[pick % len(gated)]
    run = table.runs[pick % len(table.runs)]
    if kind == "nan":
        df.loc[row, ["value", "note"]] = [math.nan, ""]
    elif kind == "inf":
        df.loc[row, "value"] = math.inf
    elif kind == "missing":
        df = df.drop(index=row)
    elif kind == "negative":
        df.loc[row, "value"] = -abs(float(df.loc[row, "value"])) - 1e-12
    elif kind == "drop_run":
        df = df[df["run"] != run]
    elif kind == "warning":
        sel = (df["run"] == run) & (df["axis"] == "other") & (df["metric"] == "n_warnings")
        assert sel.any()
        df.loc[sel, ["value", "note"]] = [1.0, "log not closed cleanly"]
    elif kind == "r_out":
        rs = df.index[(df["metric"] == "pearson_r") & df["value"].notna()]
        df.loc[rs[pick % len(rs)], "value"] = 1.0 + 1e-9
    return ResultsTable.from_dataframe(df, table.factors)


def _gate_never_passes_damage(table: ResultsTable, kind: str, pick: int) -> None:
    th = parse_thresholds(_FUZZ_RULES)
    damaged = _damage(table, kind, pick)
    verdict = check(damaged, th, expected_runs=table.runs)
    assert not verdict.passed, (kind, pick, verdict.format())
    # against the intact table as the baseline, too (only thresholds-free: the baseline gate)
    if kind != "warning":  # a warning is gated by the thresholds' allow_log_warnings
        against = check(damaged, baseline=table, expected_runs=table.runs)
        assert not against.passed, (kind, pick, against.format())


@pytest.fixture(scope="module")
def small(table: ResultsTable) -> ResultsTable:
    """Three runs of the experiment (both topics): enough places to damage, quick to gate."""
    return ResultsTable.from_dataframe(
        table.df[table.df["run"].isin(table.runs[:3])], table.factors
    )


def test_the_intact_table_passes_the_fuzz_rules(small: ResultsTable) -> None:
    assert check(small, parse_thresholds(_FUZZ_RULES), expected_runs=small.runs).passed
    assert check(small, baseline=small, expected_runs=small.runs).passed


@settings(max_examples=25, deadline=None)
@given(kind=st.sampled_from(_FUZZ_KINDS), pick=st.integers(0, 10**6))
def test_no_single_damage_passes_the_gate(small: ResultsTable, kind: str, pick: int) -> None:
    _gate_never_passes_damage(small, kind, pick)


@pytest.mark.slow
@settings(max_examples=1500, deadline=None)
@given(kind=st.sampled_from(_FUZZ_KINDS), pick=st.integers(0, 10**6))
def test_no_single_damage_passes_the_gate_long(small: ResultsTable, kind: str, pick: int) -> None:
    """The long mode of the test above (pytest -m slow): 1,500 damaged tables."""
    _gate_never_passes_damage(small, kind, pick)
