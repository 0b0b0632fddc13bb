"""The factorial analysis (uwval.results.factorial) and analysis.json: partial eta^2, F and p
cross-checked by hand (no statsmodels) on a tiny balanced design, per-level CIs, the
lag-normalised error, Pearson r's saturation, and the file's round trip."""

from __future__ import annotations

import itertools
import json
import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from scipy import stats

from uwval.errors import ConfigError
from uwval.results import ResultsTable
from uwval.results.analysis import (
    answer_sentence,
    factorial_analysis,
    read_analysis,
    write_analysis,
)

LEVELS = {"force": [5.0, 10.0], "torque": [0.1, 0.25, 0.5], "current": [0.0, 0.25]}
REPS = 2
TOPIC = "model_rov_pose"


def _design() -> list[dict[str, float]]:
    return [
        dict(zip(LEVELS, combo, strict=True))
        for combo in itertools.product(*LEVELS.values())
        for _ in range(REPS)
    ]


def _mae(run: dict[str, float], noise: float) -> float:
    """x MAE (m) of a run: current dominates, force a little, a force x current interaction."""
    return (
        0.002
        + 0.012 * run["current"]
        + 0.0001 * run["force"]
        + 0.0004 * run["force"] * run["current"]
        + noise
    )


def _table(seed: int = 0, *, r_values: list[float] | None = None) -> ResultsTable:
    rng = np.random.default_rng(seed)
    rows = []
    for i, run in enumerate(_design()):
        name = f"run{i:02d}"
        speed = 0.1 + run["current"]  # m/s
        mae = _mae(run, float(rng.normal(0, 2e-4)))
        r = r_values[i] if r_values is not None else 0.99995
        for axis, metric, value in (
            ("x", "mae", mae),
            ("x", "rmse", 1.2 * mae),
            ("x", "pearson_r", r),
            ("x", "pearson_ci_eff_low", -1.0),
            ("x", "pearson_ci_eff_high", 1.0),
            ("lag", "fitted_s", 0.0124 + float(rng.normal(0, 2e-4))),
            ("lag", "explained", 0.98),
            ("lag", "measured_s", 0.0121),
            ("lag", "speed.x", speed),
        ):
            rows.append(
                {
                    "run": name,
                    "topic": TOPIC,
                    "axis": axis,
                    "metric": metric,
                    "value": value,
                    "unit": "",
                    "note": "",
                    **run,
                }
            )
    return ResultsTable.from_dataframe(pd.DataFrame(rows), factors=list(LEVELS))


def _by_hand(y: np.ndarray, design: pd.DataFrame) -> dict[str, dict[str, float]]:
    """Balanced-design sums of squares (orthogonal terms): main effects and two-way
    interactions from cell means; the residual is what the model leaves."""
    grand = y.mean()
    df = design.assign(y=y)
    ss: dict[str, float] = {}
    dof: dict[str, int] = {}
    factors = list(LEVELS)
    for f in factors:
        m = df.groupby(f)["y"].agg(["mean", "count"])
        ss[f] = float((m["count"] * (m["mean"] - grand) ** 2).sum())
        dof[f] = len(m) - 1
    for a, b in itertools.combinations(factors, 2):
        ma = df.groupby(a)["y"].mean()
        mb = df.groupby(b)["y"].mean()
        cell = df.groupby([a, b])["y"].agg(["mean", "count"]).reset_index()
        dev = cell["mean"] - cell[a].map(ma) - cell[b].map(mb) + grand
        ss[f"{a}:{b}"] = float((cell["count"] * dev**2).sum())
        dof[f"{a}:{b}"] = dof[a] * dof[b]
    ss_res = float(((y - grand) ** 2).sum()) - sum(ss.values())
    df_res = len(y) - 1 - sum(dof.values())
    out = {}
    for term, s in ss.items():
        f_stat = (s / dof[term]) / (ss_res / df_res)
        out[term] = {
            "eta": s / (s + ss_res),
            "f": f_stat,
            "p": float(stats.f.sf(f_stat, dof[term], df_res)),
            "df": dof[term],
            "df_res": df_res,
            "ss": s,
            "total": float(((y - grand) ** 2).sum()),
        }
    return out


def test_partial_eta_squared_f_and_p_match_a_hand_computation() -> None:
    table = _table()
    doc = factorial_analysis(table)
    cell = doc["topics"][TOPIC]["x"]["mae"]
    design = table.run_factors()
    y = table.select(metric="mae", axis="x").set_index("run")["value"].reindex(design.index)
    expected = _by_hand(y.to_numpy(), design)
    got = {t["term"]: t for t in cell["terms"]}
    assert set(got) == set(expected)
    for term, e in expected.items():
        assert got[term]["partial_eta_sq"] == pytest.approx(e["eta"], rel=1e-9)
        assert got[term]["f"] == pytest.approx(e["f"], rel=1e-9)
        assert got[term]["p"] == pytest.approx(e["p"], rel=1e-6, abs=1e-300)
        assert got[term]["df"] == e["df"]
        assert got[term]["eta_sq"] == pytest.approx(e["ss"] / e["total"], rel=1e-9)
    assert cell["df_residual"] == expected["force"]["df_res"]
    # current dominates x MAE, as built
    assert got["current"]["partial_eta_sq"] > 0.9
    assert max(got, key=lambda t: got[t]["partial_eta_sq"]) == "current"


def test_level_means_cis_and_the_lag_normalised_error() -> None:
    table = _table()
    cell = factorial_analysis(table)["topics"][TOPIC]["x"]["mae"]
    design = table.run_factors()
    y = table.select(metric="mae", axis="x").set_index("run")["value"].reindex(design.index)
    hand = _by_hand(y.to_numpy(), design)
    df_res = hand["force"]["df_res"]
    ss_model = sum(e["eta"] / (1 - e["eta"]) for e in hand.values())  # each SS / SS_res, summed
    total = float(((y - y.mean()) ** 2).sum())
    ss_res = total / (1 + ss_model)
    for item in cell["levels"]["current"]:
        runs = design.index[design["current"] == item["level"]]
        vals = y[runs].to_numpy()
        assert item["n"] == vals.size == 12
        assert item["mean"] == pytest.approx(vals.mean())
        half = stats.t.ppf(0.975, df_res) * math.sqrt(ss_res / df_res / vals.size)
        assert item["ci95"] == pytest.approx([vals.mean() - half, vals.mean() + half], rel=1e-6)
        norm = vals / (0.1 + item["level"])
        assert item["normalised"] == pytest.approx(norm.mean())
        lo, hi = item["normalised_ci95"]
        assert lo < norm.mean() < hi


def test_pearson_r_near_one_everywhere_is_saturated() -> None:
    cell = factorial_analysis(_table())["topics"][TOPIC]["x"]["pearson_r"]
    assert cell["saturated"] is True
    assert "cannot rank" in cell["saturated_why"]


def test_pearson_r_whose_level_means_differ_less_than_its_ci_is_saturated() -> None:
    rng = np.random.default_rng(5)
    r = list(0.9 + rng.normal(0, 0.01, len(_design())))
    cell = factorial_analysis(_table(r_values=r))["topics"][TOPIC]["x"]["pearson_r"]
    assert cell["saturated"] is True
    assert "autocorrelation-aware" in cell["saturated_why"]


def test_lag_summary_and_answer_sentence() -> None:
    doc = factorial_analysis(_table())
    lag = doc["lag"][TOPIC]
    assert lag["n_runs"] == len(_design())
    assert lag["fitted_s_mean"] == pytest.approx(0.0124, abs=2e-4)
    assert doc["answer"] == answer_sentence(doc)
    assert doc["answer"].startswith("Unity shows Gazebo's pose 12.")
    assert "Of the variation of x MAE across runs: current" in doc["answer"]


def test_no_replicates_leaves_f_p_and_eta_undefined() -> None:
    table = _table()
    first = table.df.groupby(list(LEVELS))["run"].transform("first")
    single = ResultsTable.from_dataframe(table.df[table.df["run"] == first], factors=list(LEVELS))
    cell = factorial_analysis(single)["topics"][TOPIC]["x"]["mae"]
    # 12 cells, model with 1 + 4 + 4 (two-way) ... terms: 2 residual df remain (the 3-way)
    assert cell["df_residual"] == 2
    cell_none = factorial_analysis(
        ResultsTable.from_dataframe(
            single.df[single.df["current"] == 0.0], factors=["force", "torque"]
        )
    )["topics"][TOPIC]["x"]["mae"]
    assert cell_none["df_residual"] == 0
    assert "no residual degrees of freedom" in cell_none["note"]
    assert all(t["p"] is None and t["partial_eta_sq"] is None for t in cell_none["terms"])


def test_write_and_read_analysis_json(tmp_path: Path) -> None:
    table = _table()
    path = write_analysis(table, tmp_path)
    assert path == tmp_path / "analysis.json"
    doc = json.loads(path.read_text())
    assert doc["schema"] == "uwval.analysis/1"
    assert doc["n_runs"] == 24
    assert doc["replicates"] == {"min": 2, "max": 2}
    assert read_analysis(tmp_path) == doc
    exact = write_analysis(table, tmp_path / "sub" / "mine.json")
    assert exact == tmp_path / "sub" / "mine.json"
    (tmp_path / "bad.json").write_text("{")
    with pytest.raises(ConfigError, match="line 1"):
        read_analysis(tmp_path / "bad.json")
