"""One bridged run: Gazebo ticks -> TCP endpoint -> Unity-like client -> recorder.

DESIGN.md "Time": physics/publish ticks and Unity render frames are scheduled on one
virtual clock, while every pose really crosses a loopback TCP socket in the ROS-TCP wire
format. The Unity side's latency, drops and disconnects are modelled on that clock and
seeded, so a run is fast and reproducible; ``realtime=True`` paces the virtual clock to
the wall clock (for live peers).

How the virtual clock stays exact although bytes travel asynchronously: a message's
virtual arrival time depends only on its header stamp and the seeded fault model, never on
when the bytes showed up. Before rendering the frame at virtual time T the session reads
from the socket until every message sent up to T has been received, so the scene knows all
arrivals <= T. Ticks up to ``lookahead_s`` ahead of T are published early so the socket
carries batches instead of one round trip per frame (never across a disconnect).
"""

from __future__ import annotations

import time
from collections.abc import Iterable, Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from uwval.bridge import protocol as wire
from uwval.bridge.errors import BridgeError
from uwval.bridge.gazebo import DEFAULT_TOPICS, GazeboPublisher, Tick, ticks_from_streams
from uwval.bridge.recorder import BridgeRecorder, PoseWriter
from uwval.bridge.server import BridgeServer
from uwval.bridge.unity_client import (
    RECONNECT_DELAY_S,
    FaultModel,
    RenderLoop,
    UnityConnection,
    decode_pose_frame,
)

__all__ = ["SessionStats", "run_session", "ticks_from_streams"]

_POLL_TIMEOUT_S = 10.0


@dataclass
class SessionStats:
    """What happened in one bridged run (counts are messages unless named otherwise).

    ``sent`` poses published by the Gazebo side (``sent = delivered + dropped +
    lost_disconnected``); ``received`` read by the Unity client from the socket;
    ``delivered`` reached the scene; ``dropped`` by the fault model; ``lost_disconnected``
    sent while Unity was disconnected or still in flight when the link dropped;
    ``server_dropped`` by the endpoint's bounded queues; ``applied`` Unity transforms logged
    (one per topic per frame once a pose arrived); ``frames`` render frames. Latencies are on
    the virtual clock, seconds (None when nothing arrived or was rendered):
    ``latency_*`` arrival minus header stamp, ``render_lag_*``
    frame time minus the applied stamp.
    """

    ticks: int = 0
    sent: int = 0
    received: int = 0
    delivered: int = 0
    dropped: int = 0
    lost_disconnected: int = 0
    server_dropped: int = 0
    applied: int = 0
    frames: int = 0
    disconnects: int = 0
    reconnects: int = 0
    latency_mean_s: float | None = None
    latency_max_s: float | None = None
    render_lag_mean_s: float | None = None
    render_lag_p99_s: float | None = None
    render_lag_max_s: float | None = None
    sim_duration_s: float = 0.0
    wall_time_s: float = 0.0
    protocol: str = "ROS2"
    unity_map: str = "unity-flu"
    per_topic_applied: dict[str, int] = field(default_factory=dict)

    def as_dict(self) -> dict[str, Any]:
        """Plain JSON-able dict."""
        return asdict(self)


@dataclass
class _Flight:
    """Bookkeeping of messages the client must receive (sent while subscribed)."""

    stamps: list[int] = field(default_factory=list)  # header stamp of each, in send order
    received: int = 0

    def needed_by(self, t_ns: int) -> int:
        """How many of the sent messages have a stamp <= t_ns (stamps are sorted)."""
        return (
            int(
                np.searchsorted(
                    np.asarray(self.stamps[self.received :], dtype=np.int64), t_ns, side="right"
                )
            )
            + self.received
        )


def run_session(
    ticks: Iterable[Tick],
    writer: PoseWriter,
    *,
    unity_map: str = "unity-flu",
    frame_rate: float = 60.0,
    latency_s: float = 0.0,
    jitter_s: float = 0.0,
    drop_prob: float = 0.0,
    unity_clock_offset_s: float = 0.0,
    seed: int = 0,
    realtime: bool = False,
    protocol: str = "ROS2",
    host: str = wire.DEFAULT_HOST,
    port: int = 0,
    latency_jitter_s: float = 0.0,
    disconnects: Sequence[float] = (),
    reconnect_delay_s: float = RECONNECT_DELAY_S,
    topics: Sequence[str] = DEFAULT_TOPICS,
    lookahead_s: float = 0.2,
    flush_every: int = 1000,
) -> SessionStats:
    """Run one bridged session and record both sides through ``writer``.

    Args:
        ticks: (sim time ns, {topic: (position (3,), quat xyzw (4,))}) in ENU/FLU, in
            increasing time; any iterable (simulator output or synthetic motion).
        writer: log writer with McapPoseWriter's interface (not closed here; flushed).
        unity_map: ROS-TCP-Connector map, ``unity-flu`` or ``unity-enu``.
        frame_rate: Unity render rate, Hz.
        latency_s: one-way latency added to each message, s.
        jitter_s: std of the render-frame time jitter, s.
        drop_prob: probability that Unity loses a message.
        unity_clock_offset_s: Unity clock minus sim clock, s (Unity topics' stamps).
        seed: seeds jitter, latency jitter and drops.
        realtime: pace the virtual clock to the wall clock.
        protocol: ``ROS2`` (CDR) or ``ROS1``.
        host, port: where the endpoint listens (port 0: a free port).
        latency_jitter_s: extra uniform [0, x) per-message delay, s.
        disconnects: virtual times (s after the first tick) when Unity's connection drops;
            it reconnects and re-registers after ``reconnect_delay_s``.
        topics: topics the Unity client subscribes to and renders.
        lookahead_s: how far ahead of the render clock ticks may be sent (0 in realtime).
    """
    proto = wire.check_protocol(protocol)
    wall0 = time.perf_counter()
    stats = SessionStats(protocol=proto, unity_map=unity_map)
    faults = FaultModel(
        latency_s=latency_s,
        latency_jitter_s=latency_jitter_s,
        drop_prob=drop_prob,
        disconnects=tuple(disconnects),
        reconnect_delay_s=reconnect_delay_s,
        seed=seed,
    )
    scene = RenderLoop(
        topics,
        unity_map=unity_map,
        frame_rate=frame_rate,
        frame_jitter_s=jitter_s,
        clock_offset_s=unity_clock_offset_s,
        seed=seed,
    )
    recorder = BridgeRecorder(writer, unity_map=scene.unity_map, flush_every=flush_every)
    stats.unity_map = scene.unity_map
    lookahead_ns = 0 if realtime else int(lookahead_s * 1e9)
    max_delay_ns = round((latency_s + latency_jitter_s) * 1e9)
    latencies: list[int] = []
    lags: list[int] = []
    applied_per_topic: dict[str, int] = {t: 0 for t in topics}

    it = iter(ticks)
    first = next(it, None)
    if first is None:
        raise BridgeError("run_session: no ticks to publish")
    t0 = int(first[0])
    with BridgeServer(host, port, protocol=proto, queue_size=1 << 16) as server:
        gazebo = GazeboPublisher(server, topics=topics)
        conn = UnityConnection(
            host, server.port, subscriptions={t: wire.POSE_STAMPED for t in topics}, protocol=proto
        )

        def connect() -> None:
            conn.connect()
            _wait_registered(server, conn, topics)

        connect()
        flight = _Flight()
        # Virtual times (ns) when the link drops and when it is back.
        drops = sorted(t0 + int(d * 1e9) for d in disconnects)
        down_until: int | None = None  # while disconnected: reconnect time

        def pace(v_ns: int) -> None:
            if realtime:
                lag = (v_ns - t0) * 1e-9 - (time.perf_counter() - wall0)
                if lag > 0:
                    time.sleep(lag)

        def receive_until(count: int) -> None:
            while flight.received < count:
                frames = conn.poll(_POLL_TIMEOUT_S)
                if not frames and not conn.has_pending and flight.received < count:
                    raise BridgeError(
                        f"Unity client waited {_POLL_TIMEOUT_S} s for message "
                        f"{flight.received + 1} of {count}; the endpoint sent nothing"
                    )
                batch, arrivals = [], []
                for f in frames:
                    pose = decode_pose_frame(f, proto)
                    flight.received += 1
                    stats.received += 1
                    arrival = faults.arrival_ns(pose.stamp_ns)
                    if arrival is None:
                        stats.dropped += 1
                        continue
                    stats.delivered += 1
                    latencies.append(arrival - pose.stamp_ns)
                    batch.append(pose)
                    arrivals.append(arrival)
                scene.arrive_many(batch, arrivals)

        def publish(tick: Tick) -> None:
            t_ns, poses = int(tick[0]), tick[1]
            pace(t_ns)
            stats.ticks += 1
            for name, (pos, quat) in poses.items():
                recorder.gazebo_pose(name, t_ns, pos, quat)
                stats.sent += 1
                # Other clients (a live Unity on the same endpoint) get it too; what
                # counts here is whether our Unity-like client is linked.
                gazebo.publish(name, t_ns, pos, quat)
                if conn.connected:
                    flight.stamps.append(t_ns)
                else:
                    stats.lost_disconnected += 1

        pending: Tick | None = first
        last_tick_ns = t0
        frames = scene.frame_times(t0, 2**62)
        frame_ns = next(frames)
        while True:
            # Link events due before this frame happen first, at their own virtual time.
            while drops and drops[0] <= frame_ns and down_until is None:
                td = drops.pop(0)
                while pending is not None and int(pending[0]) < td:
                    publish(pending)
                    last_tick_ns = int(pending[0])
                    pending = next(it, None)
                receive_until(len(flight.stamps))
                in_flight = scene.discard_after(td)  # read from the socket, not yet arrived
                stats.delivered -= in_flight
                stats.lost_disconnected += in_flight
                me = _local_address(conn)
                conn.close()
                _wait_gone(server, me)  # the endpoint noticed the closed socket
                stats.disconnects += 1
                down_until = td + int(faults.reconnect_delay_s * 1e9)
            if down_until is not None and down_until <= frame_ns:
                while pending is not None and int(pending[0]) < down_until:
                    publish(pending)  # nobody subscribed: lost, as with Unity offline
                    last_tick_ns = int(pending[0])
                    pending = next(it, None)
                pace(down_until)
                connect()
                faults.reset_connection()
                flight = _Flight()
                stats.reconnects += 1
                down_until = None
            horizon = frame_ns + lookahead_ns
            if drops and down_until is None:
                horizon = min(horizon, drops[0] - 1)
            if down_until is not None:
                horizon = min(horizon, down_until - 1)
            while pending is not None and int(pending[0]) <= horizon:
                publish(pending)
                last_tick_ns = int(pending[0])
                pending = next(it, None)
            # Render until the first frame after the last message could have arrived.
            last_frame = pending is None and frame_ns > last_tick_ns + max_delay_ns
            if conn.connected:
                receive_until(flight.needed_by(frame_ns))
            pace(frame_ns)
            stats.frames += 1
            for tr in scene.render(frame_ns):
                recorder.unity_pose(
                    tr.topic, tr.unity_t_ns, tr.position, tr.orientation, tr.applied_stamp_ns
                )
                applied_per_topic[tr.topic] = applied_per_topic.get(tr.topic, 0) + 1
                lags.append(frame_ns - tr.applied_stamp_ns)
            if last_frame:
                break
            frame_ns = next(frames)
        if conn.connected:
            receive_until(len(flight.stamps))
        conn.close()
        stats.server_dropped = sum(c.dropped for c in server.clients()) + sum(
            c.dropped for c in server.closed_clients()
        )
    recorder.flush()
    stats.applied = sum(applied_per_topic.values())
    stats.per_topic_applied = applied_per_topic
    stats.sim_duration_s = (last_tick_ns - t0) * 1e-9
    if latencies:
        lat = np.asarray(latencies, dtype=np.float64) * 1e-9
        stats.latency_mean_s = float(lat.mean())
        stats.latency_max_s = float(lat.max())
    if lags:
        lag = np.asarray(lags, dtype=np.float64) * 1e-9
        stats.render_lag_mean_s = float(lag.mean())
        stats.render_lag_p99_s = float(np.percentile(lag, 99))
        stats.render_lag_max_s = float(lag.max())
    stats.wall_time_s = time.perf_counter() - wall0
    return stats


def _local_address(conn: UnityConnection) -> str:
    """``ip:port`` of the client's socket, as the endpoint lists it."""
    if conn.sock is None:
        raise BridgeError("Unity client is not connected")
    host, port = conn.sock.getsockname()[:2]
    return f"{host}:{port}"


def _wait_registered(
    server: BridgeServer, conn: UnityConnection, topics: Sequence[str], timeout: float = 5.0
) -> None:
    """Wait until the endpoint has processed this connection's ``__subscribe`` commands."""
    me = _local_address(conn)
    deadline = time.monotonic() + timeout
    while True:
        mine = [c for c in server.clients() if c.address == me]
        if mine and set(topics) <= set(mine[0].subscriptions):
            return
        if time.monotonic() > deadline:
            raise BridgeError(
                f"endpoint did not register the Unity client's subscriptions "
                f"({', '.join(topics)}) within {timeout} s"
            )
        time.sleep(0.0002)


def _wait_gone(server: BridgeServer, address: str, timeout: float = 5.0) -> None:
    """Wait until the endpoint dropped the client at ``address`` (after we closed it)."""
    deadline = time.monotonic() + timeout
    while any(c.address == address for c in server.clients()):
        if time.monotonic() > deadline:
            raise BridgeError(f"endpoint did not notice that client {address} closed")
        time.sleep(0.0002)
