"""HTML and PDF reports of uwval results: templates (jinja2) and plots (matplotlib, Agg).

``build_report(source, html_path, pdf=None, ...)`` is the entry point (see
:mod:`uwval.reports.builder`). The package uses the uwval core, never the simulator or the bridge.
"""

from uwval.reports.builder import ReportOutcome, build_report, is_log

__all__ = ["ReportOutcome", "build_report", "is_log"]
