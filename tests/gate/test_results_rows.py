"""Rows of the results table for Pearson's bookkeeping fields (issue 18, table fix)."""

from __future__ import annotations

import math
from pathlib import Path

from results_logs import CAMERA, VEHICLE, write_pair_log

from uwval.results import AXES, MISSING_NOTE, ResultsTable


def test_defined_pearson_has_no_reason_row_and_n_is_a_count(tmp_path: Path) -> None:
    from uwval.comparison import compare_logs

    lc = compare_logs(write_pair_log(tmp_path / "run.mcap", lag_s=0.05))
    t = ResultsTable.from_comparisons([("r1", {"force": 10.0}, lc)])
    df = t.to_dataframe()
    j = lc.to_json()["topics"][VEHICLE]
    # the reason is text: never a row, whether r is defined (x) or not (z never moves)
    assert j["axes"]["x"]["pearson_reason"] is None
    assert "constant" in j["axes"]["z"]["pearson_reason"]
    assert not (df["metric"] == "pearson_reason").any()
    # no row of a defined metric claims the compare JSON lacks a number
    x = df[(df["topic"] == VEHICLE) & (df["axis"] == "x")]
    assert not (x["note"] == MISSING_NOTE).any()
    assert set(x["note"]) == {""}
    # pearson_n: the sample count, unitless, for every axis and topic
    n = df[df["metric"] == "pearson_n"]
    assert len(n) == len(AXES) * len({VEHICLE, CAMERA})
    assert set(n["unit"]) == {""}
    assert t.value("r1", VEHICLE, "x", "pearson_n") == j["axes"]["x"]["pearson_n"]
    # undefined r keeps the engine's reason as its note
    z = df[(df["topic"] == VEHICLE) & (df["axis"] == "z") & (df["metric"] == "pearson_r")]
    assert math.isnan(z["value"].iloc[0])
    assert z["note"].iloc[0] == j["axes"]["z"]["pearson_reason"]
