"""The compare engine: time and frame alignment of two pose streams, and their error metrics.

``compare(reference, other, **options) -> ComparisonResult`` works on PoseStreams in memory;
``compare_logs(path_a, path_b=None, **options) -> LogComparison`` reads the streams first.
Named ``comparison`` so that the function ``uwval.compare`` does not clash with a subpackage.
"""

from uwval.comparison.align import ALIGN_MODES, Alignment, AlignMode, umeyama
from uwval.comparison.doctor import FrameDiagnosis, diagnose
from uwval.comparison.engine import AXES, SYNC_METHODS, ComparisonResult, SyncMethod, compare
from uwval.comparison.logs import LogComparison, compare_logs, read_pose_stream
from uwval.comparison.offset import OffsetEstimate, estimate_offset
from uwval.comparison.stats import norm_stats, pearson

__all__ = [
    "ALIGN_MODES",
    "AXES",
    "SYNC_METHODS",
    "AlignMode",
    "Alignment",
    "ComparisonResult",
    "FrameDiagnosis",
    "LogComparison",
    "OffsetEstimate",
    "SyncMethod",
    "compare",
    "compare_logs",
    "diagnose",
    "estimate_offset",
    "norm_stats",
    "pearson",
    "read_pose_stream",
    "umeyama",
]
