"""ResultsTable: tidy rows from real compare output, files, and the per-factor analysis."""

from __future__ import annotations

import json
import math
import warnings
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pytest
from results_logs import CAMERA, VEHICLE, write_experiment, write_pair_log
from scipy import stats

from uwval.errors import ConfigError
from uwval.results import (
    AXES,
    PAPER_METRICS,
    ResultsTable,
    anova_oneway,
    factor_levels,
    load_experiment_results,
    main_effects,
    parquet_available,
    summarize_by_level,
    two_way_pairs,
    two_way_table,
)


# ----------------------------------------------------------------------------- fixtures
@pytest.fixture(scope="module")
def experiment(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_experiment(tmp_path_factory.mktemp("exp"))


@pytest.fixture(scope="module")
def table(experiment: Path) -> ResultsTable:
    return load_experiment_results(experiment).table


# ----------------------------------------------------------------------------- rows
def test_rows_from_a_real_log_comparison(tmp_path: Path) -> None:
    from uwval.comparison import compare_logs

    log = write_pair_log(tmp_path / "run.mcap", lag_s=0.05)
    lc = compare_logs(log)
    t = ResultsTable.from_comparisons([("r1", {"force": 10.0, "mode": "teleop"}, lc)])
    df = t.to_dataframe()
    assert list(df.columns[:7]) == ["run", "topic", "axis", "metric", "value", "unit", "note"]
    assert t.factors == ["force", "mode"]
    assert t.topics == [VEHICLE, CAMERA]  # one name per topic pair, not the top-level copy
    # the paper's three metrics are present for every topic and axis
    for topic in t.topics:
        for a in AXES:
            got = set(t.select(topic=topic, axis=a)["metric"])
            assert set(PAPER_METRICS) <= got
    # values equal the compare JSON exactly
    j = lc.to_json()["topics"][VEHICLE]
    for a in AXES:
        for m in ("mae", "rmse", "max", "p95", "bias"):
            assert t.value("r1", VEHICLE, a, m) == j["axes"][a][m]
    assert t.value("r1", VEHICLE, "position_norm", "rmse") == j["position_error_norm"]["rmse"]
    assert t.value("r1", VEHICLE, "", "n_samples") == j["n_samples"]
    # units follow the axis
    units = df.set_index(["topic", "axis", "metric"])["unit"]
    assert units[(VEHICLE, "x", "mae")] == "m"
    assert units[(VEHICLE, "yaw", "mae")] == "deg"
    assert units[(VEHICLE, "x", "pearson_r")] == ""
    # z never moves: Pearson r undefined -> NaN row with the engine's reason
    z = df[(df["topic"] == VEHICLE) & (df["axis"] == "z") & (df["metric"] == "pearson_r")]
    assert len(z) == 1
    assert math.isnan(z["value"].iloc[0])
    assert "constant" in z["note"].iloc[0]
    # a 50 ms lag at 1 m/s surge gives ~5 cm MAE in x
    assert 0.03 < t.value("r1", VEHICLE, "x", "mae") < 0.07
    assert t.value("r1", VEHICLE, "x", "pearson_r") > 0.999
    assert set(df["force"]) == {10.0}
    assert set(df["mode"]) == {"teleop"}


def test_comparison_json_text_and_dict_are_accepted() -> None:
    one = {
        "n_samples": 3,
        "axes": {
            a: {
                "mae": 1.0,
                "max": 2.0,
                "pearson_r": None,
                "pearson_reason": "undefined: series is constant",
            }
            for a in AXES
        },
    }
    t1 = ResultsTable.from_comparisons([("a", None, json.dumps(one))])
    t2 = ResultsTable.from_comparisons([("a", None, one)])
    pd.testing.assert_frame_equal(t1.df, t2.df)
    assert t1.topics == [""]
    assert t1.select(metric="pearson_r")["note"].str.contains("constant").all()


@pytest.mark.parametrize(
    ("bad", "message"),
    [
        ({"n_samples": 1}, "neither 'axes'"),
        ({"axes": {"x": {"mae": 1.0}}}, "axes.y is missing"),
        ("{not json", "not valid JSON"),
        (42, "cannot read comparison results from a int"),
    ],
)
def test_bad_comparisons_are_named(bad: Any, message: str) -> None:
    with pytest.raises(ConfigError, match=message):
        ResultsTable.from_comparisons([("run7", {}, bad)])


def test_duplicate_runs_and_clashing_factors_are_rejected() -> None:
    one = {"axes": {a: {"mae": 1.0} for a in AXES}}
    with pytest.raises(ConfigError, match="run name 'a' appears twice"):
        ResultsTable.from_comparisons([("a", {}, one), ("a", {}, one)])
    with pytest.raises(ConfigError, match="factor 'metric' clashes"):
        ResultsTable.from_comparisons([("a", {"metric": 1}, one)])


# ----------------------------------------------------------------------------- files
def test_csv_json_round_trip_and_directory_save(table: ResultsTable, tmp_path: Path) -> None:
    for name in ("r.csv", "r.json"):
        (path,) = table.save(tmp_path / name)
        back = ResultsTable.load(path)
        assert back.factors == table.factors
        pd.testing.assert_frame_equal(back.df, table.df)
    written = table.save(tmp_path / "out")
    names = {p.name for p in written}
    assert {"results.csv", "results.json"} <= names
    assert ("results.parquet" in names) == parquet_available()
    obj = json.loads((tmp_path / "out" / "results.json").read_text())
    assert obj["format"] == "uwval-results"
    assert obj["factors"] == ["force", "torque", "current"]
    # NaN (undefined r) is JSON null, not the invalid token NaN
    assert "NaN" not in (tmp_path / "out" / "results.json").read_text()


def test_saving_where_nothing_can_be_written_names_the_path(
    table: ResultsTable, tmp_path: Path
) -> None:
    blocker = tmp_path / "a-file"
    blocker.write_text("x")
    for name in ("r.csv", "r.json", "out"):
        with pytest.raises(ConfigError, match=r"a-file/.*cannot write the results table"):
            table.save(blocker / name)


def test_csv_keeps_text_columns_text(tmp_path: Path) -> None:
    """Run names that look like numbers and an all-empty note column survive a CSV trip."""
    df = pd.DataFrame(
        {
            "run": ["007", "010"],
            "topic": ["t", "t"],
            "axis": ["x", "x"],
            "metric": ["mae", "mae"],
            "value": [0.5, float("nan")],
            "unit": ["m", "m"],
            "note": ["", ""],
            "force": [5.0, 10.0],
        }
    )
    table = ResultsTable.from_dataframe(df, ["force"])
    (path,) = table.save(tmp_path / "r.csv")
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # e.g. pandas' float-column fillna("") deprecation
        back = ResultsTable.load(path)
    assert back.runs == ["007", "010"]
    assert back.df["note"].tolist() == ["", ""]
    assert np.isnan(back.df["value"].iloc[1])
    pd.testing.assert_frame_equal(back.df, table.df)


def test_parquet_needs_pyarrow(table: ResultsTable, tmp_path: Path) -> None:
    if parquet_available():
        (p,) = table.save(tmp_path / "r.parquet")
        pd.testing.assert_frame_equal(ResultsTable.load(p).df, table.df)
    else:
        with pytest.raises(ConfigError, match="needs pyarrow"):
            table.save(tmp_path / "r.parquet")


def test_bad_results_files_name_the_file(tmp_path: Path) -> None:
    bad = tmp_path / "bad.json"
    bad.write_text("{")
    with pytest.raises(ConfigError, match=r"bad\.json: not valid JSON"):
        ResultsTable.load(bad)
    other = tmp_path / "other.json"
    other.write_text('{"rows": []}')
    with pytest.raises(ConfigError, match="not a uwval results JSON"):
        ResultsTable.load(other)
    csv = tmp_path / "short.csv"
    csv.write_text("run,topic,value\na,b,1\n")
    with pytest.raises(ConfigError, match=r"short\.csv: results table lacks column"):
        ResultsTable.load(csv)
    with pytest.raises(ConfigError, match="unknown results format"):
        ResultsTable.load(_touch(tmp_path / "x.txt"))
    with pytest.raises(ConfigError, match="no such results file"):
        ResultsTable.load(tmp_path / "missing.csv")
    with pytest.raises(ConfigError, match="is a directory, not a results file"):
        ResultsTable.load(tmp_path)
    junk = tmp_path / "junk.parquet"
    junk.write_bytes(b"PAR1 truncated")
    if parquet_available():
        with pytest.raises(ConfigError, match=r"junk\.parquet: not a readable Parquet file"):
            ResultsTable.load(junk)
    words = tmp_path / "words.csv"
    words.write_text(
        "run,topic,axis,metric,value,unit,note\nr1,t,x,mae,0.1,m,\n"
        "r1,t,y,mae,,m,\nr1,t,z,mae,abc,m,\n"
    )
    with pytest.raises(ConfigError, match=r"words\.csv: row 3 \(r1 t z mae\): value 'abc'"):
        ResultsTable.load(words)


def _touch(p: Path) -> Path:
    p.write_text("x")
    return p


# ----------------------------------------------------------------------------- loading
def test_experiment_directory_and_its_parts_load_the_same(experiment: Path, tmp_path: Path) -> None:
    full = load_experiment_results(experiment)
    assert len(full.runs) == 8
    assert full.manifest is not None
    assert all(r.log is not None and r.log.is_file() for r in full.runs)
    assert full.runs[0].bridge["sent"] == 200
    assert {p.name for p in full.sources} == {"comparisons.json", "manifest.json"}
    from_results_dir = load_experiment_results(experiment / "results")
    pd.testing.assert_frame_equal(from_results_dir.table.df, full.table.df)
    assert from_results_dir.manifest is not None  # found one level up
    full.table.save(tmp_path / "results.csv")
    bare = load_experiment_results(tmp_path / "results.csv")
    pd.testing.assert_frame_equal(bare.table.df, full.table.df)
    assert [r.name for r in bare.runs] == [r.name for r in full.runs]
    assert bare.runs[0].factors == full.runs[0].factors


def test_manifest_only_has_runs_but_no_rows(tmp_path: Path) -> None:
    root = write_experiment(tmp_path / "e", compare=False, reps=1)
    res = load_experiment_results(root)
    assert len(res.runs) == 4
    assert res.table.df.empty
    assert all(r.comparison is None for r in res.runs)
    with pytest.raises(ConfigError, match="no such results"):
        load_experiment_results(tmp_path / "nope")
    (tmp_path / "empty").mkdir()
    with pytest.raises(ConfigError, match="found no results table"):
        load_experiment_results(tmp_path / "empty")


# ----------------------------------------------------------------------------- analysis
def test_levels_and_varying_factors(table: ResultsTable) -> None:
    assert factor_levels(table) == {"force": [5.0, 10.0], "torque": [0.0], "current": [0.0, 0.2]}
    assert table.varying_factors() == ["force", "current"]
    assert two_way_pairs(table) == [("force", "current")]


def test_summary_per_level_matches_pandas(table: ResultsTable) -> None:
    s = summarize_by_level(table, "current")
    row = s[
        (s["current"] == 0.2)
        & (s["topic"] == VEHICLE)
        & (s["axis"] == "x")
        & (s["metric"] == "mae")
    ].iloc[0]
    vals = table.df[
        (table.df["current"] == 0.2)
        & (table.df["topic"] == VEHICLE)
        & (table.df["axis"] == "x")
        & (table.df["metric"] == "mae")
    ]["value"]
    assert row["n"] == 4
    assert row["mean"] == pytest.approx(vals.mean())
    assert row["std"] == pytest.approx(vals.std(ddof=1))
    z = s[(s["topic"] == VEHICLE) & (s["axis"] == "z") & (s["metric"] == "pearson_r")]
    assert (z["n_undefined"] == 4).all()
    assert (z["n"] == 0).all()
    with pytest.raises(ConfigError, match="no factor 'speed'"):
        summarize_by_level(table, "speed")


def test_current_raises_the_error_as_built_in(table: ResultsTable) -> None:
    # the test experiment lags Unity by 0.3 s per 1 m/s of current: MAE x must grow with it
    me = main_effects(table, metric="mae")
    cur = me[(me["factor"] == "current") & (me["topic"] == VEHICLE) & (me["axis"] == "x")]
    lo, hi = cur.sort_values("level")["mean"].to_numpy()
    assert hi > lo * 1.3
    assert cur["effect"].iloc[0] == pytest.approx(hi - lo)


def test_anova_equals_scipy_and_flags_undefined_cases(table: ResultsTable) -> None:
    an = anova_oneway(table, "current")
    row = an[(an["topic"] == VEHICLE) & (an["axis"] == "x")].iloc[0]
    sub = table.df[
        (table.df["topic"] == VEHICLE) & (table.df["axis"] == "x") & (table.df["metric"] == "mae")
    ]
    groups = [g["value"].to_numpy() for _, g in sub.groupby("current")]
    ref = stats.f_oneway(*groups)
    assert row["f_stat"] == pytest.approx(ref.statistic)
    assert row["p_value"] == pytest.approx(ref.pvalue)
    assert (row["df_between"], row["df_within"]) == (1, 6)
    assert row["p_value"] < 0.05  # the built-in lag effect is significant
    one = anova_oneway(table, "torque")
    assert one["f_stat"].isna().all()
    assert (one["note"] == "torque has one level only").all()
    single = ResultsTable.from_dataframe(
        table.df[table.df["run"].str.endswith("current0_rep0")], table.factors
    )
    norep = anova_oneway(single, "force")
    assert norep["note"].str.contains("no replicate").all()


def test_two_way_table_cells_are_means(table: ResultsTable) -> None:
    tw = two_way_table(table, "force", "current", topic=VEHICLE, axis="x")
    assert list(tw.index) == [5.0, 10.0]
    assert list(tw.columns) == [0.0, 0.2]
    df = table.df
    cell = df[
        (df["force"] == 10.0)
        & (df["current"] == 0.2)
        & (df["topic"] == VEHICLE)
        & (df["axis"] == "x")
        & (df["metric"] == "mae")
    ]["value"].mean()
    assert tw.at[10.0, 0.2] == pytest.approx(cell)


def test_wide_view_has_one_row_per_run(table: ResultsTable) -> None:
    w = table.wide()
    assert list(w.index) == table.runs
    assert (VEHICLE, "x", "mae") in w.columns
    assert (CAMERA, "yaw", "pearson_r") in w.columns
