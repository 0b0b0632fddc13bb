"""Options of one bridged run (:class:`SessionOptions`) and the constants they default to.

Kept free of heavy imports (no numpy, no sockets) so that the command line can build and
check options when it starts; the bridge's classes that own the rules are imported when an
option is checked.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

from uwval.errors import ConfigError

if TYPE_CHECKING:
    from uwval.bridge.connector_reader import ConnectorReader
    from uwval.bridge.unity_client import FaultModel, RenderLoop

#: How Unity takes messages off the socket (``SessionOptions.reader``): ``connector``
#: (ROS-TCP-Connector's background reader: 10 ms idle sleeps), ``immediate`` (at arrival),
#: ``auto`` (the Connector's whenever the transport models a real link, i.e. not ``ideal``).
READERS = ("auto", "connector", "immediate")

#: Topics of uwval's Gazebo side (``/gazebo/<name>``) and of the Unity client's scene.
VEHICLE_TOPIC = "model_rov_pose"
CAMERA_TOPIC = "gui_camera_pose"
DEFAULT_TOPICS = (VEHICLE_TOPIC, CAMERA_TOPIC)
#: Unity's ROS-TCP-Connector reconnects this long after a lost connection, s.
RECONNECT_DELAY_S = 1.0
#: Where the endpoint listens by default (ROS-TCP-Endpoint's loopback address).
DEFAULT_HOST = "127.0.0.1"

__all__ = [
    "CAMERA_TOPIC",
    "DEFAULT_HOST",
    "DEFAULT_TOPICS",
    "LOG_SUFFIX",
    "REAL_UNITY",
    "RECONNECT_DELAY_S",
    "VEHICLE_TOPIC",
    "SessionOptions",
]

#: Log file suffix of each log format a session can record into (``uwval simulate --format``).
LOG_SUFFIX = {
    "mcap": ".mcap",
    "rosbag2": "",
    "rosbag2-sqlite3": "",
    "rosbag2-mcap": "",
    "rosbag1": ".bag",
}


#: A Unity side as a real setup has it (:mod:`uwval.bridge.unity_model` says where each
#: number comes from): ROS-TCP-Endpoint 0.7.0's link timing, a 60 Hz vsync display that
#: misses a vsync now and then, float32 Transforms, a quartz clock 20 ppm fast.
REAL_UNITY: dict[str, object] = {
    "transport": "real-endpoint",
    "frame_model": "vsync",
    "frame_rate": 60.0,
    "stall_prob": 0.005,
    "float32": True,
    "clock_drift_ppm": 20.0,
}


@dataclass(frozen=True)
class SessionOptions:
    """How one bridged run behaves: the link, the Unity-like client and the recording.

    Times in seconds, rates in Hz. Every option is checked when the options are made (one
    clean :class:`ConfigError`/:class:`BridgeError` before any simulation runs); the
    bridge's own classes (:class:`FaultModel`, :class:`RenderLoop`) own the rules.

    Attributes:
        unity_map: ROS-TCP-Connector map, ``unity-flu`` or ``unity-enu``.
        frame_rate: Unity render rate.
        latency_s: one-way latency added to each message.
        jitter_s: std of the render-frame time jitter.
        drop_prob: probability that Unity loses a message.
        unity_clock_offset_s: Unity clock minus sim clock (Unity topics' stamps).
        realtime: pace the virtual clock to the wall clock.
        protocol: ``ROS2`` (CDR) or ``ROS1``.
        log_format: ``mcap``, ``rosbag2``/``rosbag2-sqlite3`` or ``rosbag1`` (the recording).
        latency_jitter_s: extra uniform [0, x) per-message delay.
        disconnects: virtual times (s after the first tick) when Unity's connection drops;
            it reconnects and re-registers after ``reconnect_delay_s``.
        reconnect_delay_s: how long Unity stays away after a drop.
        topics: topics the Unity client subscribes to and renders.
        lookahead_s: how far ahead of the render clock ticks may be sent (0 in realtime).
        flush_every: the recorder flushes after this many messages.
        host, port: where the endpoint listens (port 0: a free port).
        transport: link timing model (:mod:`uwval.bridge.unity_model`): ``ideal``,
            ``nodelay`` or ``real-endpoint`` (Nagle + delayed ACK as measured on
            ROS-TCP-Endpoint 0.7.0).
        frame_model: ``fixed``, ``vsync`` (display refresh ``frame_rate``, missed vsyncs)
            or ``trace`` (frame durations from ``frame_trace``).
        stall_prob: ``vsync``: probability that a frame misses its vsync.
        frame_trace: ``trace``: file of frame durations (s), one per line.
        float32: Unity's Transform stores float32.
        clock_drift_ppm: Unity's clock rate error, parts per million.
        reader: how Unity takes messages off the socket, one of :data:`READERS`.

    These defaults are the exact building block (no link delay, fixed frames, float64);
    :data:`REAL_UNITY` holds the values of a real setup, the defaults of ``uwval simulate``
    and of the default experiment.
    """

    unity_map: str = "unity-flu"
    frame_rate: float = 60.0
    latency_s: float = 0.0
    jitter_s: float = 0.0
    drop_prob: float = 0.0
    unity_clock_offset_s: float = 0.0
    realtime: bool = False
    protocol: str = "ROS2"
    log_format: str = "mcap"
    latency_jitter_s: float = 0.0
    disconnects: tuple[float, ...] = ()
    reconnect_delay_s: float = RECONNECT_DELAY_S
    topics: tuple[str, ...] = DEFAULT_TOPICS
    lookahead_s: float = 1.0
    flush_every: int = 1000
    host: str = DEFAULT_HOST
    port: int = 0
    transport: str = "ideal"
    frame_model: str = "fixed"
    stall_prob: float = 0.005
    frame_trace: str | None = None
    float32: bool = False
    clock_drift_ppm: float = 0.0
    reader: str = "auto"

    def __post_init__(self) -> None:
        from uwval.bridge import protocol as wire

        object.__setattr__(self, "disconnects", tuple(float(d) for d in self.disconnects))
        object.__setattr__(self, "topics", tuple(self.topics))
        if self.log_format not in LOG_SUFFIX:
            raise ConfigError(
                f"--format {self.log_format!r}: choose one of {', '.join(LOG_SUFFIX)}"
            )
        wire.check_protocol(self.protocol)
        if self.reader not in READERS:
            raise ConfigError(f"reader {self.reader!r}: choose one of {', '.join(READERS)}")
        self.fault_model(0)
        self.render_loop(0)

    def connector_reader(self, seed: int) -> ConnectorReader | None:
        """ROS-TCP-Connector's reader for a run seeded ``seed``, or None (``immediate``)."""
        from uwval.bridge.connector_reader import ConnectorReader

        use = self.reader == "connector" or (self.reader == "auto" and self.transport != "ideal")
        return ConnectorReader(seed=seed) if use else None

    def fault_model(self, seed: int) -> FaultModel:
        """The Unity side's link faults for a run seeded ``seed``."""
        from uwval.bridge.unity_client import FaultModel

        return FaultModel(
            latency_s=self.latency_s,
            latency_jitter_s=self.latency_jitter_s,
            drop_prob=self.drop_prob,
            disconnects=self.disconnects,
            reconnect_delay_s=self.reconnect_delay_s,
            seed=seed,
            transport=self.transport,
        )

    def render_loop(self, seed: int) -> RenderLoop:
        """The Unity-like scene for a run seeded ``seed``."""
        from uwval.bridge.unity_client import RenderLoop

        return RenderLoop(
            self.topics,
            unity_map=self.unity_map,
            frame_rate=self.frame_rate,
            frame_jitter_s=self.jitter_s,
            clock_offset_s=self.unity_clock_offset_s,
            seed=seed,
            frame_model=self.frame_model,
            stall_prob=self.stall_prob,
            frame_trace=self.frame_trace,
            float32=self.float32,
            clock_drift_ppm=self.clock_drift_ppm,
        )
