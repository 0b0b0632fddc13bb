"""Issue 16: complete tables when stdout is a file or a pipe (CI logs): no column squeezed to
"1.27e-…", every column of compare's table, and the demo says which file holds the full table.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from cli_runner import run_uwval

from uwval.io.tum import write_tum
from uwval.posestream import PoseStream


def _pair(tmp_path: Path) -> tuple[Path, Path]:
    rng = np.random.default_rng(3)
    n = 400
    t = np.arange(n, dtype=np.int64) * 10_000_000 + 5_000_000_000
    s = np.arange(n) * 0.01
    pos = np.stack([np.cos(s), np.sin(s), 0.2 * s], axis=1)
    quat = np.tile([0.0, 0.0, 0.0, 1.0], (n, 1))
    ref = PoseStream.from_arrays(t, pos, quat)
    oth = PoseStream.from_arrays(t, pos + rng.normal(0, 1.27e-4, (n, 3)), quat)
    a, b = tmp_path / "gt.txt", tmp_path / "est.txt"
    write_tum(a, ref)
    write_tum(b, oth)
    return a, b


def test_compare_table_to_a_pipe_is_complete(tmp_path: Path) -> None:
    a, b = _pair(tmp_path)
    p = run_uwval("compare", a, b)  # stdout is a pipe here
    assert p.returncode == 0, p.stderr
    doc = json.loads(run_uwval("compare", a, b, "--json").stdout)
    header = next(line for line in p.stdout.splitlines() if line.strip().startswith("axis"))
    for col in (
        "MAE",
        "RMSE",
        "max",
        "bias",
        "Pearson r",
        "p95",
        "median",
        "std",
        "Pearson 95% CI",
    ):
        assert col in header
    assert "…" not in p.stdout and "..." not in p.stdout
    x = next(line for line in p.stdout.splitlines() if line.strip().startswith("x [m]"))
    # 10 significant digits of every value, as in the JSON
    assert f"{doc['axes']['x']['mae']:.10g}" in x
    assert f"{doc['axes']['x']['p95']:.10g}" in x
    # no line is wrapped: the title names both files on one line
    assert any(str(a) in line and str(b) in line for line in p.stdout.splitlines())


def test_demo_summary_to_a_pipe_is_not_cut(capsys: pytest.CaptureFixture[str]) -> None:
    from uwval.cli.demo_cmd import _print_summary

    axes = {
        ax: {"mae": 1.2734567e-05, "pearson_r": 0.99999123}
        for ax in ("x", "y", "z", "roll", "pitch", "yaw")
    }
    factors = {f"factor_{i}": 0.123456 for i in range(8)}
    runs = [
        {
            "factors": factors,
            "comparison": {"axes": axes, "position_error_norm": {"max": 3.4567e-05}},
        }
    ] * 3
    _print_summary(runs)
    out = capsys.readouterr().out
    assert "…" not in out
    assert out.count("1.27e-05") == 6 and "factor_7" in out
