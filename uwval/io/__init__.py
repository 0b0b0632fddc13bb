"""Log I/O: read pose streams from logs and write uwval's own logs.

Readers: MCAP, ROS 1 bags, rosbag2 (sqlite3 / MCAP), bare .db3, Unity CSV and TUM text,
with a vectorised fast path for fixed-layout pose messages. Writers: MCAP (default),
rosbag2 and ROS 1 bags, incremental (``open_writer``) or bulk (``write_stream``).

The names below are imported on first use, so that ``uwval.io.tum`` (the TUM text path of
``uwval compare``) does not pay for the log readers' imports.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from uwval.io.csv_io import read_csv
    from uwval.io.mcap_io import McapPoseWriter
    from uwval.io.raw import TopicInfo, TruncatedLogWarning
    from uwval.io.reader import list_topics, read_stream, read_streams, topic_times
    from uwval.io.writers import (
        PoseLogWriter,
        Rosbag1PoseWriter,
        Rosbag2PoseWriter,
        open_writer,
        write_stream,
    )

#: Public name -> module that defines it.
_HOME = {
    "read_csv": "uwval.io.csv_io",
    "McapPoseWriter": "uwval.io.mcap_io",
    "TopicInfo": "uwval.io.raw",
    "TruncatedLogWarning": "uwval.io.raw",
    "list_topics": "uwval.io.reader",
    "read_stream": "uwval.io.reader",
    "read_streams": "uwval.io.reader",
    "topic_times": "uwval.io.reader",
    "PoseLogWriter": "uwval.io.writers",
    "Rosbag1PoseWriter": "uwval.io.writers",
    "Rosbag2PoseWriter": "uwval.io.writers",
    "open_writer": "uwval.io.writers",
    "write_stream": "uwval.io.writers",
}

__all__ = [
    "McapPoseWriter",
    "PoseLogWriter",
    "Rosbag1PoseWriter",
    "Rosbag2PoseWriter",
    "TopicInfo",
    "TruncatedLogWarning",
    "list_topics",
    "open_writer",
    "read_csv",
    "read_stream",
    "read_streams",
    "topic_times",
    "write_stream",
]


def __getattr__(name: str) -> Any:
    """Import a public name from its module on first use (PEP 562)."""
    if name in _HOME:
        value = getattr(importlib.import_module(_HOME[name]), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'uwval.io' has no attribute {name!r}")
