"""The compare JSON's lag, drift and effective-n fields become rows of the results table,
with their units (uwval.results.schema)."""

from __future__ import annotations

import numpy as np
import pytest

from uwval.comparison import compare
from uwval.posestream import PoseStream
from uwval.results import ResultsTable


def _stream(t: np.ndarray, pos: np.ndarray) -> PoseStream:
    q = np.tile([0.0, 0.0, 0.0, 1.0], (t.size, 1))
    return PoseStream.from_arrays(np.round(t * 1e9).astype(np.int64), pos, q, frame="enu")


def test_lag_rows_carry_their_units() -> None:
    t = np.arange(0, 10, 0.02)
    path = np.column_stack([np.sin(t), 0.5 * np.cos(0.7 * t), 0.1 * t])
    late = np.column_stack([np.sin(t - 0.01), 0.5 * np.cos(0.7 * (t - 0.01)), 0.1 * (t - 0.01)])
    res = compare(_stream(t, path), _stream(t, late))
    table = ResultsTable.from_comparisons([("run0", {"force": 1.0}, res)])
    df = table.df.set_index(["axis", "metric"])
    assert df.loc[("lag", "fitted_s"), "value"] == pytest.approx(0.01, rel=0.02)
    assert df.loc[("lag", "fitted_s"), "unit"] == "s"
    assert df.loc[("lag", "ci95_s_low"), "unit"] == "s"
    assert df.loc[("lag", "speed.x"), "unit"] == "m/s"
    assert df.loc[("lag", "residual.x.mae"), "unit"] == "m"
    assert df.loc[("lag", "explained"), "unit"] == ""
    assert df.loc[("offset", "drift_ppm"), "value"] == 0.0
    assert df.loc[("offset", "drift_ppm"), "unit"] == "ppm"
    assert df.loc[("x", "pearson_n_eff"), "value"] < 500
    assert df.loc[("x", "pearson_ci_eff_low"), "value"] <= df.loc[("x", "pearson_r"), "value"]
