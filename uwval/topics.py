"""The topics of uwval's logs, and which of them a compare of one log reads. No numpy here:
the command line uses them before the heavy modules load."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

VEHICLE = "model_rov_pose"
CAMERA = "gui_camera_pose"
GAZEBO_PREFIX = "/gazebo/"
UNITY_PREFIX = "/unity/"
DEFAULT_GAZEBO_TOPIC = GAZEBO_PREFIX + VEHICLE
DEFAULT_UNITY_TOPIC = UNITY_PREFIX + VEHICLE


def log_topics(
    pairs: Sequence[Any] | None, gazebo_topic: str | None, unity_topic: str | None
) -> tuple[list[str], bool]:
    """The topics :func:`uwval.comparison.compare_logs` reads from one log, and whether
    missing ones are skipped: the project file's pairs (``reference``, ``other``) when no
    topic is given; the given pair (a missing side: the vehicle's default); otherwise every
    candidate of the vehicle and camera pairs."""
    if pairs and not (gazebo_topic or unity_topic):
        return [t for p in pairs for t in (p.reference, p.other)], False
    if gazebo_topic or unity_topic:
        return [gazebo_topic or DEFAULT_GAZEBO_TOPIC, unity_topic or DEFAULT_UNITY_TOPIC], False
    return [p + name for name in (VEHICLE, CAMERA) for p in (GAZEBO_PREFIX, UNITY_PREFIX)], True
