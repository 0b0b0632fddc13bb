"""Log I/O: read pose streams from logs and write uwval's own logs.

Readers: MCAP, ROS 1 bags, rosbag2 (sqlite3 / MCAP), bare .db3, Unity CSV and TUM text,
with a vectorised fast path for fixed-layout pose messages. Writers: MCAP (default),
rosbag2 and ROS 1 bags, incremental (``open_writer``) or bulk (``write_stream``).
"""

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
