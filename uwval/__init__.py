"""uwval: prove that an underwater vehicle's pose in Unity matches Gazebo's.

The core package: pose streams, frames, log I/O, alignment, metrics and the CLI.
It imports none of ``simulator``, ``bridge`` or ``reports`` (only the CLI wires them in).
"""

from uwval.errors import UwvalError
from uwval.posestream import PoseStream

__version__ = "0.1.0"

__all__ = ["PoseStream", "UwvalError", "__version__"]
