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
from array import array
from bisect import bisect_right
from collections.abc import Iterable, Sequence
from dataclasses import asdict, dataclass, field, replace
from typing import Any

import numpy as np

from uwval.bridge import protocol as wire
from uwval.bridge.connector_reader import VirtualPort
from uwval.bridge.errors import BridgeError
from uwval.bridge.gazebo import (
    GazeboPublisher,
    Tick,
    ticks_from_streams,
)
from uwval.bridge.options import LOG_SUFFIX, SessionOptions
from uwval.bridge.recorder import BridgeRecorder, PoseWriter
from uwval.bridge.server import BridgeServer
from uwval.bridge.unity_client import ReceivedPose, UnityConnection, decode_pose_frame

__all__ = [
    "LOG_SUFFIX",
    "BridgeSession",
    "SessionOptions",
    "SessionStats",
    "run_session",
    "ticks_from_streams",
]

_POLL_TIMEOUT_S = 10.0
#: Longer than any delay of the non-ideal transports (delayed ACK 40 ms + wire), ns.
LINK_DELAY_BOUND_NS = 60_000_000


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


class _Flight:
    """Bookkeeping of messages the client must receive (sent while subscribed).

    Holds the header stamps of the messages sent but not yet received only (an hour-long
    run does not keep every stamp it ever sent); ``sent`` and ``received`` count them all.
    """

    def __init__(self) -> None:
        self._stamps = array("q")  # stamps of sent messages from index ``_base`` on
        self._base = 0
        self.sent = 0
        self.received = 0

    def add(self, t_ns: int) -> None:
        self._stamps.append(t_ns)
        self.sent += 1

    def got(self, n: int) -> None:
        """``n`` more messages were received (in send order)."""
        self.received += n
        drop = self.received - self._base
        if drop > 4096 and drop * 2 > len(self._stamps):
            del self._stamps[:drop]
            self._base = self.received

    def needed_by(self, t_ns: int) -> int:
        """How many of the sent messages have a stamp <= t_ns (stamps are sorted)."""
        lo = self.received - self._base
        return bisect_right(self._stamps, t_ns, lo) + self._base


class BridgeSession:
    """One bridged run on the virtual clock: publish ticks, carry them over TCP, render, record.

    ``BridgeSession(writer, options, seed=...).run(ticks)`` publishes the Gazebo side's
    ticks into a real :class:`BridgeServer`, reads them back through a Unity-like
    :class:`UnityConnection` on a loopback socket, renders frames with a :class:`RenderLoop`
    and records both sides through a :class:`BridgeRecorder` on ``writer`` (flushed, not
    closed). Memory does not grow with the run's length: ticks are consumed as they come
    (any iterable: a streamed simulation), statistics are kept as 8-byte stamps.
    """

    def __init__(self, writer: PoseWriter, options: SessionOptions | None = None, *, seed: int = 0):
        self.options = opts = options if options is not None else SessionOptions()
        self.protocol = wire.check_protocol(opts.protocol)
        self.seed = int(seed)
        self.faults = opts.fault_model(self.seed)
        self.scene = opts.render_loop(self.seed)
        #: ROS-TCP-Connector's reader (idle 10 ms sleeps) on the virtual clock, or None:
        #: what reaches the socket is in the scene at once.
        self.reader = opts.connector_reader(self.seed)
        self._port: VirtualPort[ReceivedPose] = VirtualPort(self._read)
        # the recorder hands uwval's writers blocks of messages encoded at once
        self.recorder = BridgeRecorder(
            writer, unity_map=self.scene.unity_map, flush_every=opts.flush_every
        )
        self.stats = SessionStats(protocol=self.protocol, unity_map=self.scene.unity_map)
        self._latencies = array("q")
        self._lags = array("q")
        self._applied: dict[str, int] = {t: 0 for t in opts.topics}
        self._flight = _Flight()
        self._t0 = 0
        self._wall0 = 0.0
        self._last_tick_ns = 0
        self._pending: Tick | None = None
        self._ticks: Any = iter(())

    # ------------------------------------------------------------------ the run
    def run(self, ticks: Iterable[Tick]) -> SessionStats:
        """Publish every tick (ENU/FLU poses, increasing sim time ns) and render until the
        last message could have arrived; return the run's statistics."""
        opts, stats, scene = self.options, self.stats, self.scene
        self._wall0 = time.perf_counter()
        self._ticks = iter(ticks)
        first = next(self._ticks, None)
        if first is None:
            raise BridgeError("run_session: no ticks to publish")
        self._t0 = self._last_tick_ns = int(first[0])
        self._pending = first
        lookahead_ns = 0 if opts.realtime else int(opts.lookahead_s * 1e9)
        max_delay_ns = round((opts.latency_s + opts.latency_jitter_s) * 1e9)
        if opts.transport != "ideal":  # a pose held by Nagle until a delayed ACK: ~41 ms
            max_delay_ns += LINK_DELAY_BOUND_NS
        if self.reader is not None:  # and then a reader's idle sleep
            max_delay_ns += self.reader.sleep_ns
        # Virtual times (ns) when the link drops and when it is back.
        drops = sorted(self._t0 + int(d * 1e9) for d in opts.disconnects)
        down_until: int | None = None  # while disconnected: reconnect time
        with BridgeServer(
            opts.host, opts.port, protocol=self.protocol, queue_size=1 << 16
        ) as server:
            self.server = server
            self.gazebo = GazeboPublisher(server, topics=opts.topics)
            self.conn = UnityConnection(
                opts.host,
                server.port,
                subscriptions={t: wire.POSE_STAMPED for t in opts.topics},
                protocol=self.protocol,
            )
            self._connect()
            self.faults.reset_connection(self._t0)
            self._start_reader(self._t0)
            frames = scene.frame_times(self._t0, 2**62)
            frame_ns = next(frames)
            while True:
                # Link events due before this frame happen first, at their own virtual time.
                while drops and drops[0] <= frame_ns and down_until is None:
                    down_until = self._disconnect(drops.pop(0))
                if down_until is not None and down_until <= frame_ns:
                    self._reconnect(down_until)
                    down_until = None
                horizon = frame_ns + lookahead_ns
                if drops and down_until is None:
                    horizon = min(horizon, drops[0] - 1)
                if down_until is not None:
                    horizon = min(horizon, down_until - 1)
                self._publish_through(horizon)
                # Render until the first frame after the last message could have arrived.
                last_frame = self._pending is None and frame_ns > self._last_tick_ns + max_delay_ns
                if self.conn.connected:
                    self._receive_until(self._flight.needed_by(frame_ns))
                    if self.reader is not None:
                        self.reader.run(self._port, frame_ns)
                self._pace(frame_ns)
                self._render(frame_ns)
                if self.conn.connected:  # as the Connector does, or the endpoint's idle
                    self.conn.keepalive_if_idle()  # timeout closes a run longer than 5 s wall
                if last_frame:
                    break
                frame_ns = next(frames)
            if self.conn.connected:
                self._receive_until(self._flight.sent)
            self.conn.close()
            stats.server_dropped = sum(c.dropped for c in server.clients()) + sum(
                c.dropped for c in server.closed_clients()
            )
        self.recorder.flush()
        return self._finish()

    # ------------------------------------------------------------------ steps of a run
    def _connect(self) -> None:
        self.conn.connect()
        _wait_registered(self.server, self.conn, self.options.topics)

    def _pace(self, v_ns: int) -> None:
        if self.options.realtime:
            lag = (v_ns - self._t0) * 1e-9 - (time.perf_counter() - self._wall0)
            if lag > 0:
                time.sleep(lag)

    def _publish_through(self, horizon_ns: int) -> None:
        """Publish the pending ticks stamped <= ``horizon_ns``."""
        while self._pending is not None and int(self._pending[0]) <= horizon_ns:
            self._publish(self._pending)
            self._last_tick_ns = int(self._pending[0])
            self._pending = next(self._ticks, None)

    def _publish(self, tick: Tick) -> None:
        t_ns, poses = int(tick[0]), tick[1]
        stats = self.stats
        self._pace(t_ns)
        stats.ticks += 1
        linked = self.conn.connected
        for name, (pos, quat) in poses.items():
            self.recorder.gazebo_pose(name, t_ns, pos, quat)
            stats.sent += 1
            # Other clients (a live Unity on the same endpoint) get it too; what counts
            # here is whether our Unity-like client is linked.
            self.gazebo.publish(name, t_ns, pos, quat)
            if linked:
                self._flight.add(t_ns)
            else:
                stats.lost_disconnected += 1

    def _receive_until(self, count: int) -> None:
        """Read from the socket until ``count`` of the sent messages were received."""
        flight, stats, faults = self._flight, self.stats, self.faults
        while flight.received < count:
            frames = self.conn.poll(_POLL_TIMEOUT_S)
            if not frames and not self.conn.has_pending and flight.received < count:
                raise BridgeError(
                    f"Unity client waited {_POLL_TIMEOUT_S} s for message "
                    f"{flight.received + 1} of {count}; the endpoint sent nothing"
                )
            batch, arrivals = [], []
            for f in frames:
                pose = decode_pose_frame(f, self.protocol)
                arrival = faults.arrival_ns(pose.stamp_ns)
                if arrival is None:
                    stats.dropped += 1
                    continue
                stats.delivered += 1
                batch.append(pose)
                arrivals.append(arrival)
            flight.got(len(frames))
            stats.received += len(frames)
            if self.reader is not None:
                self._port.add(batch, arrivals)  # the reader picks them up
            else:
                self._read(batch, arrivals)

    def _start_reader(self, at_ns: int) -> None:
        """A (re)connect at ``at_ns``: the reader's first look comes a seeded phase later."""
        if self.reader is not None:
            self._port.start(at_ns + self.reader.phase_ns())

    def _read(self, poses: list[ReceivedPose], read_ns: list[int]) -> None:
        """Poses Unity's reader handed to ``Update`` at ``read_ns`` (virtual ns)."""
        for pose, t in zip(poses, read_ns, strict=True):
            self._latencies.append(t - pose.stamp_ns)
        self.scene.arrive_many(poses, read_ns)

    def _render(self, frame_ns: int) -> None:
        self.stats.frames += 1
        for tr in self.scene.render(frame_ns):
            self.recorder.unity_pose(
                tr.topic, tr.unity_t_ns, tr.position, tr.orientation, tr.applied_stamp_ns
            )
            self._applied[tr.topic] = self._applied.get(tr.topic, 0) + 1
            self._lags.append(frame_ns - tr.applied_stamp_ns)

    def _disconnect(self, td: int) -> int:
        """The link drops at virtual time ``td``; returns when Unity is back."""
        stats = self.stats
        while self._pending is not None and int(self._pending[0]) < td:
            self._publish(self._pending)
            self._last_tick_ns = int(self._pending[0])
            self._pending = next(self._ticks, None)
        self._receive_until(self._flight.sent)
        in_flight = 0
        if self.reader is not None:  # the reader reads until the link drops; the rest is lost
            self.reader.run(self._port, td)
            in_flight = self._port.drop_all()
        in_flight += self.scene.discard_after(td)  # read from the socket, not yet arrived
        stats.delivered -= in_flight
        stats.lost_disconnected += in_flight
        me = _local_address(self.conn)
        self.conn.close()
        _wait_gone(self.server, me)  # the endpoint noticed the closed socket
        stats.disconnects += 1
        return td + int(self.faults.reconnect_delay_s * 1e9)

    def _reconnect(self, at_ns: int) -> None:
        """Unity comes back at ``at_ns``; ticks until then reach nobody (Unity offline)."""
        while self._pending is not None and int(self._pending[0]) < at_ns:
            self._publish(self._pending)
            self._last_tick_ns = int(self._pending[0])
            self._pending = next(self._ticks, None)
        self._pace(at_ns)
        self._connect()
        self.faults.reset_connection(at_ns)
        self._start_reader(at_ns)
        self._flight = _Flight()
        self.stats.reconnects += 1

    def _finish(self) -> SessionStats:
        stats = self.stats
        stats.applied = sum(self._applied.values())
        stats.per_topic_applied = dict(self._applied)
        stats.sim_duration_s = (self._last_tick_ns - self._t0) * 1e-9
        if self._latencies:
            lat = np.frombuffer(self._latencies, dtype=np.int64).astype(np.float64) * 1e-9
            stats.latency_mean_s = float(lat.mean())
            stats.latency_max_s = float(lat.max())
        if self._lags:
            lag = np.frombuffer(self._lags, dtype=np.int64).astype(np.float64) * 1e-9
            stats.render_lag_mean_s = float(lag.mean())
            stats.render_lag_p99_s = float(np.percentile(lag, 99))
            stats.render_lag_max_s = float(lag.max())
        stats.wall_time_s = time.perf_counter() - self._wall0
        return stats


def run_session(
    ticks: Iterable[Tick],
    writer: PoseWriter,
    options: SessionOptions | None = None,
    *,
    seed: int = 0,
    **overrides: Any,
) -> SessionStats:
    """Run one bridged session and record both sides through ``writer`` (flushed, not closed).

    ``ticks``: (sim time ns, {topic: (position (3,), quat xyzw (4,))}) in ENU/FLU, in
    increasing time; any iterable (a streamed simulation, synthetic motion). ``options``
    (default :class:`SessionOptions`) with any of its fields overridden by keyword
    (``latency_s=0.02``); ``seed`` seeds jitter, latency jitter and drops.
    """
    opts = options if options is not None else SessionOptions()
    if overrides:
        unknown = set(overrides) - set(SessionOptions.__dataclass_fields__)
        if unknown:
            raise TypeError(f"run_session: unknown option(s) {', '.join(sorted(unknown))}")
        opts = replace(opts, **overrides)
    return BridgeSession(writer, opts, seed=seed).run(ticks)


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
