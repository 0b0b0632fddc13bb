"""uwval: prove that an underwater vehicle's pose in Unity matches Gazebo's.

The core package: pose streams, frames, log I/O, alignment, metrics and the CLI.
It imports none of ``simulator``, ``bridge`` or ``reports`` (only the CLI wires them in).
"""

from typing import TYPE_CHECKING, Any

from uwval.errors import UwvalError

if TYPE_CHECKING:
    from uwval.posestream import PoseStream

__version__ = "0.1.0"

__all__ = [
    "ComparisonResult",
    "LogComparison",
    "PoseStream",
    "UwvalError",
    "__version__",
    "compare",
    "compare_logs",
]

_LAZY = {"compare", "compare_logs", "ComparisonResult", "LogComparison"}


def __dir__() -> list[str]:
    """The module's names, the lazily imported ones included."""
    return sorted({*globals(), *__all__})


def __getattr__(name: str) -> Any:
    """``uwval.compare``, ``uwval.PoseStream`` etc., imported on first use.

    ``import uwval`` stays free of numpy, so that the command line can set up the process
    (e.g. the BLAS thread count of ``uwval compare``) before numpy loads.
    """
    if name == "PoseStream":
        from uwval.posestream import PoseStream

        return PoseStream
    if name in _LAZY:
        import uwval.comparison as comparison

        return getattr(comparison, name)
    raise AttributeError(f"module 'uwval' has no attribute {name!r}")
