"""Serve a recorded Gazebo-side log to connecting Unity clients (``uwval bridge replay``).

The Gazebo topics of a log (``/gazebo/model_rov_pose``, ``/gazebo/gui_camera_pose`` by
default) are published through a :class:`~uwval.bridge.server.BridgeServer` on their ROS topic
names (``model_rov_pose``, ...) at the recorded pace divided by ``speed``, with their
recorded header stamps, so a real Unity scene can be driven from a recorded Gazebo run.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from uwval.bridge.errors import BridgeError
from uwval.bridge.gazebo import GazeboPublisher, Tick, paced, ticks_from_streams
from uwval.bridge.server import BridgeServer
from uwval.io import read_stream

DEFAULT_REPLAY_TOPICS = ("/gazebo/model_rov_pose", "/gazebo/gui_camera_pose")


@dataclass
class ReplayStats:
    """Counts of one replay pass: ticks, messages published, deliveries, wall time (s)."""

    ticks: int = 0
    published: int = 0
    delivered: int = 0
    loops: int = 0
    wall_time_s: float = 0.0
    log_duration_s: float = 0.0

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


def ros_topic_name(log_topic: str) -> str:
    """``/gazebo/model_rov_pose`` -> ``model_rov_pose`` (the name Unity subscribes to)."""
    return log_topic.strip("/").split("/")[-1]


def check_replay_options(speed: float, loops: int) -> None:
    """Raise BridgeError unless ``speed`` >= 0 (0/inf: as fast as possible) and ``loops``
    >= 0 (0: forever)."""
    if not speed >= 0:  # also NaN
        raise BridgeError(f"replay speed must be >= 0, got {speed}")
    if loops < 0:
        raise BridgeError(f"replay loops must be >= 0 (0 = forever), got {loops}")


def load_replay_ticks(
    path: str | Path, topics: Sequence[str] = DEFAULT_REPLAY_TOPICS
) -> list[Tick]:
    """Read a log's Gazebo topics into ticks named by their ROS topic basenames."""
    streams = [read_stream(path, t) for t in topics]
    ticks = list(ticks_from_streams(*streams, names=[ros_topic_name(t) for t in topics]))
    if not ticks:
        raise BridgeError(f"{path}: nothing to replay on {', '.join(topics)}")
    return ticks


def replay_log(
    path: str | Path,
    server: BridgeServer,
    *,
    topics: Sequence[str] = DEFAULT_REPLAY_TOPICS,
    speed: float = 1.0,
    loops: int = 1,
    wait_for_subscriber_s: float | None = 30.0,
    should_stop: Callable[[], bool] | None = None,
    progress: Callable[[int, int], None] | None = None,
    ticks: list[Tick] | None = None,
) -> ReplayStats:
    """Publish a log's Gazebo poses through ``server`` at recorded speed x ``speed``.

    Args:
        path: the log (any format ``uwval.io.read_stream`` reads).
        server: a started server.
        topics: log topics to replay; each is published on its basename.
        speed: playback speed factor (2 = twice as fast); ``0`` or ``inf`` = as fast
            as possible.
        loops: how many passes (0 = until ``should_stop``).
        wait_for_subscriber_s: first wait this long for a client subscribed to the first
            topic (None: do not wait).
        should_stop: polled between ticks; True ends the replay.
        progress: called with (ticks done, ticks per pass).
        ticks: already loaded with :func:`load_replay_ticks` (then ``path`` is not read).
    """
    check_replay_options(speed, loops)
    if ticks is None:
        ticks = load_replay_ticks(path, topics)
    names = [ros_topic_name(t) for t in topics]
    publisher = GazeboPublisher(server, topics=names)
    if wait_for_subscriber_s is not None:
        server.wait_for_subscribers(names[0], 1, timeout=wait_for_subscriber_s)
    stats = ReplayStats(log_duration_s=(ticks[-1][0] - ticks[0][0]) * 1e-9)
    wall0 = time.perf_counter()
    n_pass = 0
    while loops == 0 or n_pass < loops:
        for k, tick in enumerate(paced(ticks, speed)):
            if should_stop is not None and should_stop():
                stats.wall_time_s = time.perf_counter() - wall0
                return stats
            reached = publisher.publish_tick(tick)
            stats.ticks += 1
            stats.published += len(reached)
            stats.delivered += sum(reached.values())
            if progress is not None:
                progress(k + 1, len(ticks))
        n_pass += 1
        stats.loops = n_pass
    stats.wall_time_s = time.perf_counter() - wall0
    return stats
