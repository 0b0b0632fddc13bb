"""pytest plugin: gate Gazebo/Unity pose correspondence in your own CI test suite.

Enable it in ``conftest.py``::

    pytest_plugins = ["uwval.pytest_plugin"]

(or run ``pytest -p uwval.pytest_plugin``). Then, in a test::

    from uwval.pytest_plugin import assert_pose_correspondence

    def test_vehicle_matches(tmp_path):
        # a log recorded by your Gazebo + Unity rig, or uwval's own simulate output
        assert_pose_correspondence("logs/run.mcap", "ci/thresholds.toml")

    def test_experiment(uwval_check):
        # thresholds/baseline from --uwval-thresholds / --uwval-baseline or the ini keys
        uwval_check("results/")

``results`` may be a log (compared on the spot, vehicle + camera topics), a results location
(experiment dir, ``results/``, ``results.csv/json``, ``comparisons.json``), a ResultsTable,
or a LogComparison/ComparisonResult (or its JSON dict). ``thresholds`` a TOML path, a dict
in the same shape, or a parsed :class:`uwval.gate.Thresholds`. A failure lists every
regressed value (metric, topic, axis, factor levels, value, bound).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import pytest

from uwval.gate import GateResult, Thresholds, check, parse_thresholds
from uwval.results import ResultsTable, load_experiment_results

ResultsLike = ResultsTable | str | Path | Mapping[str, Any] | Any
ThresholdsLike = Thresholds | str | Path | Mapping[str, Any] | None

_LOG_SUFFIXES = (".mcap", ".bag", ".db3")


def as_results_table(results: ResultsLike) -> ResultsTable:
    """Whatever the user has (see the module doc) -> a ResultsTable."""
    if isinstance(results, ResultsTable):
        return results
    if isinstance(results, (str, Path)):
        p = Path(results)
        is_log = (p.is_file() and p.suffix.lower() in _LOG_SUFFIXES) or (
            p.is_dir() and (p / "metadata.yaml").is_file()
        )
        if is_log:
            from uwval.comparison import compare_logs

            return ResultsTable.from_comparisons([(p.stem or p.name, {}, compare_logs(p))])
        return load_experiment_results(p).table
    return ResultsTable.from_comparisons([("run", {}, results)])


def _as_thresholds(thresholds: ThresholdsLike) -> Thresholds | str | Path | None:
    if isinstance(thresholds, Mapping):
        return parse_thresholds(thresholds, source="<thresholds dict>")
    return thresholds


def gate(
    results: ResultsLike,
    thresholds: ThresholdsLike = None,
    baseline: ResultsTable | str | Path | None = None,
) -> GateResult:
    """Run the gate and return its result (no assertion).

    A results location with a manifest also gates that every run of the manifest has results.
    """
    expected: list[str] = []
    location = Path(results) if isinstance(results, (str, Path)) else None
    if location is not None and location.is_dir() and not (location / "metadata.yaml").is_file():
        exp = load_experiment_results(location)
        if not exp.table.df.empty:
            results, expected = exp.table, [r.name for r in exp.runs]
    return check(
        as_results_table(results),
        _as_thresholds(thresholds),
        baseline,
        expected_runs=expected,
    )


def assert_pose_correspondence(
    results: ResultsLike,
    thresholds: ThresholdsLike = None,
    baseline: ResultsTable | str | Path | None = None,
) -> GateResult:
    """Assert that ``results`` pass the thresholds and/or baseline; the AssertionError
    message lists every regression. Returns the (passing) GateResult."""
    verdict = gate(results, thresholds, baseline)
    if not verdict.passed:
        raise AssertionError(verdict.format(limit=None))
    return verdict


def pytest_addoption(parser: pytest.Parser) -> None:
    group = parser.getgroup("uwval", "uwval pose-correspondence gate")
    group.addoption(
        "--uwval-thresholds", default=None, help="thresholds TOML used by the uwval_check fixture"
    )
    group.addoption(
        "--uwval-baseline",
        default=None,
        help="golden baseline (results JSON/CSV) used by the uwval_check fixture",
    )
    parser.addini("uwval_thresholds", "thresholds TOML for the uwval_check fixture", default="")
    parser.addini("uwval_baseline", "golden baseline for the uwval_check fixture", default="")


def _configured(config: pytest.Config, name: str) -> str | None:
    """The configured path: a command-line option relative to where pytest was started
    (as any path typed in a shell), an ini key relative to the ini file's folder."""
    value = config.getoption(f"--uwval-{name}")
    if value:
        base = Path(config.invocation_params.dir)
    else:
        value = config.getini(f"uwval_{name}")
        if not value:
            return None
        base = config.inipath.parent if config.inipath is not None else config.rootpath
    p = Path(str(value))
    return str(p if p.is_absolute() else base / p)


@pytest.fixture
def uwval_check(request: pytest.FixtureRequest) -> Callable[..., GateResult]:
    """``uwval_check(results, thresholds=None, baseline=None)``: assert the gate passes.

    Unset thresholds/baseline come from ``--uwval-thresholds`` / ``--uwval-baseline`` or the
    ``uwval_thresholds`` / ``uwval_baseline`` ini keys (options relative to the directory
    pytest was started in, ini keys to the ini file's directory).
    """
    config = request.config

    def _check(
        results: ResultsLike,
        thresholds: ThresholdsLike = None,
        baseline: ResultsTable | str | Path | None = None,
    ) -> GateResult:
        th = thresholds if thresholds is not None else _configured(config, "thresholds")
        base = baseline if baseline is not None else _configured(config, "baseline")
        if th is None and base is None:
            pytest.fail(
                "uwval_check: no thresholds or baseline (pass them, or set "
                "--uwval-thresholds / uwval_thresholds in the ini file)"
            )
        verdict = gate(results, th, base)
        if not verdict.passed:
            pytest.fail(verdict.format(limit=None), pytrace=False)
        return verdict

    return _check
