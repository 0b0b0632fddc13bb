"""The tidy results table of an experiment, and its analysis per factor level.

Four parts, one module each:

- :mod:`uwval.results.schema`: the compare JSON (the engine's one schema) -> rows;
  axes, units and the metric names every table uses.
- :mod:`uwval.results.table`: :class:`ResultsTable`, its columns and its files.
- :mod:`uwval.results.analysis`: summaries per level, main effects, ANOVA, two-way tables;
  :mod:`uwval.results.factorial`: the factorial analysis and ``analysis.json``.
- :mod:`uwval.results.experiment`: loading a sweep's manifest, comparisons and tables.

Every public name stays importable from ``uwval.results``.
"""

from __future__ import annotations

from uwval.results.analysis import (
    ROUNDOFF_FLOOR,
    AnovaRow,
    anova_oneway,
    answer_sentence,
    factor_levels,
    factorial_analysis,
    main_effects,
    read_analysis,
    roundoff_axes,
    summarize_by_level,
    two_way_pairs,
    two_way_table,
    write_analysis,
)
from uwval.results.experiment import (
    ExperimentResults,
    ManifestRun,
    RunRecord,
    compare_pending,
    load_experiment_results,
    read_manifest,
)
from uwval.results.schema import (
    AXES,
    AXIS_METRICS,
    AXIS_UNITS,
    CORE_COLUMNS,
    FACTOR_UNITS,
    MAY_BE_UNDEFINED,
    MISSING_NOTE,
    PAPER_METRICS,
    POSITION_AXES,
    ROTATION_AXES,
    comparison_warnings,
    factor_label,
    flatten_result,
    topic_results,
)
from uwval.results.table import ResultsTable, parquet_available

__all__ = [
    "AXES",
    "AXIS_METRICS",
    "AXIS_UNITS",
    "CORE_COLUMNS",
    "FACTOR_UNITS",
    "MAY_BE_UNDEFINED",
    "MISSING_NOTE",
    "PAPER_METRICS",
    "POSITION_AXES",
    "ROTATION_AXES",
    "ROUNDOFF_FLOOR",
    "AnovaRow",
    "ExperimentResults",
    "ManifestRun",
    "ResultsTable",
    "RunRecord",
    "anova_oneway",
    "answer_sentence",
    "compare_pending",
    "comparison_warnings",
    "factor_label",
    "factor_levels",
    "factorial_analysis",
    "flatten_result",
    "load_experiment_results",
    "main_effects",
    "parquet_available",
    "read_analysis",
    "read_manifest",
    "roundoff_axes",
    "summarize_by_level",
    "topic_results",
    "two_way_pairs",
    "two_way_table",
    "write_analysis",
]
