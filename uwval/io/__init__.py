"""Log I/O: read pose streams from logs and write uwval's own logs."""

from uwval.io.reader import TopicInfo, list_topics, read_stream

__all__ = ["TopicInfo", "list_topics", "read_stream"]
