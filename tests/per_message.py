"""The recorder's per-message write path, for the tests that compare it with the block path."""

from __future__ import annotations

from typing import Any


class PerMessage:
    """The per-message path: a writer the recorder cannot hand blocks to (no write_blocks),
    whose every message is encoded by the writer's own write_pose / write_header."""

    def __init__(self, writer: Any) -> None:
        self.writer = writer

    def write_pose(self, *args: Any) -> None:
        self.writer.write_pose(*args)

    def write_header(self, *args: Any) -> None:
        self.writer.write_header(*args)

    def flush(self) -> None:
        self.writer.flush()

    def close(self) -> None:
        self.writer.close()
