"""The CI gate: check a results table against thresholds and/or a golden baseline.

Thresholds live in a TOML file (format documented in ``THRESHOLDS_FORMAT`` and
``data/thresholds/default.toml``)::

    version = 1
    # allow_log_warnings = false       # a run whose log a reader warned about (not closed
                                       # cleanly, messages dropped) fails unless true

    [[threshold]]
    name = "vehicle position MAE"      # optional, shown in the report
    metric = "mae"                     # a results-table metric (mae, max, rmse, p95, pearson_r...)
    axes = ["x", "y", "z"]             # default: all of x y z roll pitch yaw
    topics = ["model_rov_pose"]        # fnmatch patterns; default ["*"]
    # roles = ["vehicle"]              # or ["camera"], ["any"]: by role, not name (a topic
                                       # label naming a camera is the camera, any other
                                       # the vehicle); no topic of the role: rule skipped
    max = 0.05                         # fail when value > max (units of the axis: m or deg)
    # min = 0.99                       # fail when value < min
    # factors = { current = 0.2 }      # only runs at these factor levels
    # undefined = "skip"               # Pearson r undefined with the engine's reason
                                       # (a constant series): skip | fail

    [baseline]                         # tolerances for --baseline golden.json
    rtol = 0.25                        # relative slack on error metrics
    atol_m = 0.002                     # absolute slack, metres
    atol_deg = 0.05                    # absolute slack, degrees
    atol_r = 0.01                      # Pearson r may drop this much
    r_min = 0.9                        # baseline r below this (noise-level axis): not gated
    metrics = ["mae", "rmse", "max", "p95", "pearson_r"]

A rule that matches no row is itself a failure (a typo must not pass silently; a rule keyed
by ``roles`` is skipped instead, with a note), and so is a
run the rule should cover (by its factor levels) that has no row for one of its axes.
A gated value that is NaN or missing fails, unless it may be undefined by definition: a
Pearson statistic the engine left undefined with its reason (fewer than 3 samples, a
constant series), which a rule's ``undefined = "skip"`` (the default) skips, reason shown.
An impossible value (a negative MAE/RMSE/max/p95/std, |r| > 1) fails. A run that a reader
warned about (a log not closed cleanly, messages dropped) fails unless ``allow_log_warnings``.
Runs of the manifest without results fail. Against a
baseline (a results table saved as JSON/CSV), error metrics regress when
``value > base * (1 + rtol) + atol``, Pearson r when ``value < base - atol_r``, bias when
``|value| > |base| * (1 + rtol) + atol``; a baseline r below ``r_min`` is not gated (an
axis that barely moves has a noise-level, meaningless correlation); a run, topic or axis
present in the baseline but missing from the results is a failure too, as is a run or topic
of the results the baseline does not cover. A baseline that holds no gated value, or an error
metric that is NaN or negative, is refused (exit 2): it cannot gate anything. A gated metric
(``[baseline] metrics``) that the baseline lacks for a run/topic/axis it covers is a failure
that names the metric: a baseline of Pearson r alone cannot pass a regressed MAE.

Results that do not say what their log readers dropped and warned about (``dropped`` and
``warnings`` of each source of a compare JSON, ``n_warnings`` rows of a table) are refused
(:func:`require_integrity`, exit 2). ``default`` names the embedded thresholds or baseline.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from uwval.errors import ConfigError
from uwval.gate.checks import (
    baseline_from,
    baseline_gaps,
    check_baseline,
    check_log_warnings,
    check_runs,
    check_thresholds,
    check_values,
)
from uwval.gate.integrity import (
    DEFAULT_NAME,
    GateInputError,
    display_path,
    missing_integrity,
    require_integrity,
    resolve_input,
)
from uwval.gate.rules import (
    ABS_IS_WORSE,
    DEFAULT_BASELINE_METRICS,
    ERROR_AXES,
    HIGHER_IS_WORSE,
    LOWER_IS_WORSE,
    NON_NEGATIVE,
    BaselineTolerance,
    ThresholdRule,
    Thresholds,
    UndefinedPolicy,
    load_thresholds,
    parse_thresholds,
)
from uwval.gate.verdict import GateResult, Violation, ViolationKind
from uwval.results import ResultsTable

THRESHOLDS_FORMAT = __doc__ or ""

__all__ = [
    "ABS_IS_WORSE",
    "DEFAULT_BASELINE_METRICS",
    "DEFAULT_NAME",
    "ERROR_AXES",
    "HIGHER_IS_WORSE",
    "LOWER_IS_WORSE",
    "NON_NEGATIVE",
    "THRESHOLDS_FORMAT",
    "BaselineTolerance",
    "GateInputError",
    "GateResult",
    "ThresholdRule",
    "Thresholds",
    "UndefinedPolicy",
    "Violation",
    "ViolationKind",
    "baseline_from",
    "baseline_gaps",
    "check",
    "check_baseline",
    "check_log_warnings",
    "check_results",
    "check_runs",
    "check_thresholds",
    "check_values",
    "display_path",
    "load_thresholds",
    "missing_integrity",
    "parse_thresholds",
    "require_integrity",
    "resolve_input",
]


def check(
    table: ResultsTable,
    thresholds: Thresholds | str | Path | None = None,
    baseline: ResultsTable | str | Path | None = None,
    *,
    expected_runs: Sequence[str] = (),
) -> GateResult:
    """The gate: thresholds and/or baseline (paths are loaded; ``"default"`` names the
    embedded file). At least one is required.

    Besides the rules and the baseline, every gate run also fails impossible values
    (:func:`check_values`), runs whose logs a reader warned about unless the thresholds allow
    it (:func:`check_log_warnings`) and ``expected_runs`` (e.g. the manifest's) that have no
    results (:func:`check_runs`).
    """
    if thresholds is None and baseline is None:
        raise ConfigError("uwval check needs --thresholds FILE.toml and/or --baseline FILE.json")
    if isinstance(thresholds, (str, Path)):
        th: Thresholds | None = load_thresholds(resolve_input("thresholds", thresholds) or "")
    else:
        th = thresholds
    if th is not None and not th.rules and baseline is None:
        # an empty rule list would pass every table: a gate that checks nothing is a mistake
        raise ConfigError(
            f"{th.source}: defines no threshold rules and no --baseline was given: nothing to check"
        )
    if table.df.empty:
        raise ConfigError("the results hold no rows: nothing to check")
    result = check_values(table)
    result = result.merge(check_runs(table, expected_runs, "the manifest"))
    allow = th.allow_log_warnings if th is not None else False
    result = result.merge(check_log_warnings(table, allow=allow))
    if th is not None:
        result = result.merge(check_thresholds(table, th))
    if baseline is not None:
        if isinstance(baseline, (str, Path)):
            base = ResultsTable.load(resolve_input("baselines", baseline) or "")
        else:
            base = baseline
        tol = th.baseline if th is not None else BaselineTolerance()
        result = result.merge(check_baseline(table, base, tol))
    return result


#: Alias used by ``uwval demo``: the gate over an in-memory results table.
check_results = check
