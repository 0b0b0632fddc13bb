"""A Unity-like ROS-TCP-Connector client: connection, faults and render loop.

Three parts, so the same behaviour runs on a virtual clock (``run_session``) or the wall
clock (:meth:`UnityClient.run_realtime`, e.g. against ``uwval bridge replay``):

- :class:`UnityConnection` is the socket side of Unity's ``ROSConnection``: it connects,
  checks the endpoint's ``__handshake`` (version v0.7.*), sends a keepalive, registers its
  subscriptions (``__subscribe``, with Unity's trailing NULs in ROS 2 mode), receives frames
  and sends keepalives when idle. It re-registers everything on each (re)connect.
- :class:`FaultModel` turns each received message into a (virtual) arrival time with
  latency, optional latency jitter and random drops, seeded; TCP keeps arrivals in order.
- :class:`RenderLoop` is the scene: at each render frame it applies, per topic, the latest
  pose that has arrived, converted from ROS (ENU world / FLU body) into Unity axes with the
  configured ROS-TCP-Connector map, and reports an :class:`AppliedTransform` stamped with
  Unity's own clock (frame time + clock offset) and the header stamp it applied.

Size: one module on purpose: the connection, fault model and render loop are the three halves
of one client and are tested together; each part is a class of ~150 lines.
"""

from __future__ import annotations

import contextlib
import math
import socket
import threading
import time
from collections import deque
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from uwval.bridge import protocol as wire
from uwval.bridge.connector_reader import ConnectorReader, wall_sleep_ns
from uwval.bridge.errors import BridgeError
from uwval.bridge.unity_model import FrameClock, Transport, float32_transform, read_frame_trace
from uwval.frames import convert_arrays, get_convention

#: Unity's ROS-TCP-Connector reconnects this long after a lost connection, s. Stated again in
#: :mod:`uwval.bridge.options` (which must not import this module: it is imported lazily from
#: there); tests/test_bridge_client.py keeps the two equal.
RECONNECT_DELAY_S = 1.0

F64 = NDArray[np.float64]

#: Unity's ROSConnection sends a keepalive after this long without sending anything.
KEEPALIVE_INTERVAL_S = 1.0


@dataclass(frozen=True)
class ReceivedPose:
    """A PoseStamped as received: header stamp (ns), ROS-frame pose, receive wall time (ns)."""

    topic: str
    stamp_ns: int
    position: F64
    orientation: F64
    frame_id: str
    recv_wall_ns: int


@dataclass(frozen=True)
class AppliedTransform:
    """One Unity frame's transform of one object.

    ``unity_t_ns`` is Unity's clock (virtual frame time + offset); ``position`` and
    ``orientation`` are in Unity axes under ``unity_map``; ``applied_stamp_ns`` is the
    Gazebo header stamp of the pose shown; ``frame_t_ns`` is the frame's virtual time.
    """

    topic: str
    unity_t_ns: int
    frame_t_ns: int
    position: F64
    orientation: F64
    applied_stamp_ns: int


class ProtocolMismatchError(BridgeError):
    """The endpoint's handshake names another protocol than the one the client was set to."""


def epoch_minus_monotonic_ns() -> int:
    """Wall clock (Unix epoch) minus ``time.monotonic_ns()`` now, ns (midpoint of two reads)."""
    m0 = time.monotonic_ns()
    e = time.time_ns()
    m1 = time.monotonic_ns()
    return e - (m0 + m1) // 2


class UnityConnection:
    """Client side of ROS-TCP-Connector v0.7 on a real socket.

    Args:
        host, port: the endpoint.
        subscriptions: topic -> ``pkg/Type`` to register with ``__subscribe``.
        publications: topic -> ``pkg/Type`` to register with ``__publish``.
        protocol: the protocol this "Unity project" was built for; a mismatch with the
            endpoint's handshake raises :class:`ProtocolMismatchError` (Unity logs an error
            there). ``"auto"`` takes the protocol the handshake announces.
        nul: append Unity's trailing NUL to destinations and JSON (ROS 2 Unity does);
            None: as the protocol in use does.
        on_message: called with (``__log``/``__warn``/``__error``, text) as each arrives.
    """

    def __init__(
        self,
        host: str = wire.DEFAULT_HOST,
        port: int = wire.DEFAULT_PORT,
        *,
        subscriptions: dict[str, str] | None = None,
        publications: dict[str, str] | None = None,
        protocol: wire.Protocol | Literal["auto"] = "ROS2",
        nul: bool | None = None,
        max_frame: int = wire.MAX_FRAME_BYTES,
        on_message: Callable[[str, str], None] | None = None,
    ) -> None:
        self.host = host
        self.port = port
        self.subscriptions = dict(subscriptions or {})
        self.publications = dict(publications or {})
        #: The protocol asked for (``"auto"``: whatever the endpoint's handshake says).
        self.requested_protocol: wire.Protocol | Literal["auto"] = (
            "auto" if protocol == "auto" else wire.check_protocol(protocol)
        )
        #: The protocol in use: the requested one, or after an ``auto`` connect the endpoint's.
        self.protocol: wire.Protocol = "ROS2" if protocol == "auto" else protocol
        self._nul_option = nul
        self.nul = (self.protocol == "ROS2") if nul is None else nul
        self.on_message = on_message
        #: ``__log`` / ``__warn`` / ``__error`` frames received, per command.
        self.message_counts: dict[str, int] = {wire.LOG: 0, wire.WARN: 0, wire.ERROR: 0}
        self.max_frame = max_frame
        self.sock: socket.socket | None = None
        self._parser = wire.FrameParser(max_frame)
        self._pending: list[wire.Frame] = []
        self._last_send = 0.0
        self.server_version = ""
        self.connects = 0
        #: ``__log`` / ``__warn`` / ``__error`` texts received from the endpoint.
        self.messages: list[tuple[str, str]] = []
        #: Other system commands received (e.g. ``__topic_list`` replies), in order.
        self.commands: list[wire.Frame] = []

    @property
    def connected(self) -> bool:
        """True while the socket is open."""
        return self.sock is not None

    @property
    def has_pending(self) -> bool:
        """True when complete frames are parsed but not yet returned by :meth:`poll`."""
        return bool(self._pending)

    def connect(self, timeout: float = 5.0) -> None:
        """Connect, read and check the handshake, send a keepalive, register topics."""
        self.close()
        try:
            sock = socket.create_connection((self.host, self.port), timeout=timeout)
        except (OSError, OverflowError) as exc:
            raise BridgeError(f"cannot connect to {self.host}:{self.port}: {exc}") from exc
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self.sock = sock
        self._parser = wire.FrameParser(self.max_frame)
        self._pending = []
        try:
            first = self._next_frame(timeout)
            while first.is_keepalive:  # older endpoints send a keepalive before the handshake
                first = self._next_frame(timeout)
            self.server_version, server_protocol = wire.parse_handshake(first)
            if self.requested_protocol == "auto":
                self.protocol = server_protocol
                self.nul = (server_protocol == "ROS2") if self._nul_option is None else self.nul
            elif server_protocol != self.requested_protocol:
                raise ProtocolMismatchError(
                    f"protocol mismatch: endpoint {self.host}:{self.port} speaks "
                    f"{server_protocol}, this client was built for {self.requested_protocol} "
                    f"(the endpoint's handshake says {server_protocol}; use --protocol "
                    f"{server_protocol} or auto)"
                )
            out = [wire.KEEPALIVE]
            for topic, name in self.subscriptions.items():
                out.append(
                    wire.encode_command(
                        wire.SUBSCRIBE, {"topic": topic, "message_name": name}, nul=self.nul
                    )
                )
            for topic, name in self.publications.items():
                out.append(
                    wire.encode_command(
                        wire.PUBLISH,
                        {
                            "topic": topic,
                            "message_name": name,
                            "queue_size": 10,
                            "latch": False,
                        },
                        nul=self.nul,
                    )
                )
            self._send(b"".join(out))
        except BaseException:
            self.close()
            raise
        sock.settimeout(None)
        self.connects += 1

    def close(self) -> None:
        """Close the socket (no goodbye: the protocol has none)."""
        if self.sock is not None:
            with contextlib.suppress(OSError):
                self.sock.shutdown(socket.SHUT_RDWR)
            self.sock.close()
            self.sock = None

    def _send(self, data: bytes) -> None:
        if self.sock is None:
            raise BridgeError("not connected")
        try:
            self.sock.sendall(data)
        except OSError as exc:
            self.close()
            raise BridgeError(f"send to {self.host}:{self.port} failed: {exc}") from exc
        self._last_send = time.monotonic()

    def send_command(self, command: str, params: dict[str, object] | None = None) -> None:
        """Send one system command (JSON payload)."""
        self._send(wire.encode_command(command, dict(params or {}), nul=self.nul))

    def publish(self, topic: str, body: bytes) -> None:
        """Send a message on a topic registered with ``__publish``."""
        self._send(wire.encode_frame(topic, body, nul=self.nul))

    def keepalive_if_idle(self, interval: float = KEEPALIVE_INTERVAL_S) -> None:
        """Send 8 zero bytes when nothing was sent for ``interval`` seconds, as Unity does."""
        if self.sock is not None and time.monotonic() - self._last_send >= interval:
            self._send(wire.KEEPALIVE)

    def receive(self, timeout: float | None) -> bool:
        """Read once from the socket into the frame parser (``timeout`` 0: only what is
        already there, without changing the socket's blocking mode, so another thread may
        send meanwhile); False when nothing came. Raises BridgeError on EOF or a lost link."""
        if self.sock is None:
            raise BridgeError("not connected")
        try:
            if timeout == 0.0:
                data = self.sock.recv(1 << 16, socket.MSG_DONTWAIT)
            else:
                self.sock.settimeout(timeout)
                data = self.sock.recv(1 << 16)
        except (TimeoutError, BlockingIOError):
            return False
        except OSError as exc:
            self.close()
            raise BridgeError(f"connection to {self.host}:{self.port} lost: {exc}") from exc
        if not data:
            self.close()
            raise BridgeError(f"endpoint {self.host}:{self.port} closed the connection")
        self._pending.extend(self._parser.feed(data))
        return True

    def _next_frame(self, timeout: float) -> wire.Frame:
        deadline = time.monotonic() + timeout
        while not self._pending:
            left = deadline - time.monotonic()
            if left <= 0 or not self.receive(left):
                raise BridgeError(f"no frame from {self.host}:{self.port} within {timeout} s")
        return self._pending.pop(0)

    def poll(self, timeout: float | None = 0.0) -> list[wire.Frame]:
        """Topic frames received so far (waiting up to ``timeout`` s for the first bytes).

        System commands are handled here (logs kept in :attr:`messages`, others in
        :attr:`commands`); keepalives are dropped. ``timeout=None`` blocks.
        """
        if self.sock is None:
            raise BridgeError("not connected")
        if not self._pending:
            self.receive(timeout)
        return self.take_frames()

    def take_frames(self) -> list[wire.Frame]:
        """The topic frames parsed so far (system commands handled, keepalives dropped)."""
        frames, self._pending = self._pending, []
        out = []
        for f in frames:
            if f.is_keepalive:
                continue
            if f.is_command:
                if f.destination in (wire.LOG, wire.WARN, wire.ERROR):
                    text = str(f.json().get("text", ""))
                    self.messages.append((f.destination, text))
                    self.message_counts[f.destination] += 1
                    if self.on_message is not None:
                        self.on_message(f.destination, text)
                else:
                    self.commands.append(f)
                continue
            out.append(f)
        return out


#: Messages' random numbers drawn at once by :class:`FaultModel` (same sequence as one by one).
_DRAW_BLOCK = 1024


@dataclass
class FaultModel:
    """Faults injected on the Unity side, on the virtual clock, seeded.

    ``latency_s`` is added to every message's send time, ``latency_jitter_s`` adds a
    uniform [0, jitter) delay per message; arrivals stay in send order as TCP keeps them.
    ``drop_prob`` drops a received message before the scene sees it.
    ``disconnects`` lists virtual times (s from the start of the run) at which the
    connection drops: the socket is really closed, and Unity reconnects and re-registers
    after ``reconnect_delay_s``; messages in flight or sent meanwhile are lost.
    ``transport`` (:mod:`uwval.bridge.unity_model`): ``ideal`` (no link delay of its own),
    ``nodelay`` or ``real-endpoint`` (Nagle + delayed ACK of ROS-TCP-Endpoint 0.7.0);
    its delay comes before ``latency_s`` and the jitter.
    """

    latency_s: float = 0.0
    latency_jitter_s: float = 0.0
    drop_prob: float = 0.0
    disconnects: Sequence[float] = ()
    reconnect_delay_s: float = RECONNECT_DELAY_S
    seed: int = 0
    transport: str = "ideal"
    _rng: np.random.Generator = field(init=False, repr=False)
    _link: Transport = field(init=False, repr=False)
    _last_arrival_ns: int = field(default=-(2**62), init=False, repr=False)
    _draws: list[float] = field(default_factory=list, init=False, repr=False)
    _next: int = field(default=0, init=False, repr=False)

    def __post_init__(self) -> None:
        # ``not x >= 0`` also rejects NaN (which compares false with everything).
        if not (self.latency_s >= 0 and self.latency_jitter_s >= 0) or not (
            math.isfinite(self.latency_s) and math.isfinite(self.latency_jitter_s)
        ):
            raise BridgeError(
                f"latency and latency jitter must be finite and >= 0 s, got "
                f"{self.latency_s} and {self.latency_jitter_s}"
            )
        if not 0.0 <= self.drop_prob <= 1.0:
            raise BridgeError(f"drop probability must be in [0, 1], got {self.drop_prob}")
        if not (0 < self.reconnect_delay_s < math.inf):
            raise BridgeError(
                f"reconnect delay must be finite and > 0 s, got {self.reconnect_delay_s}"
            )
        if not all(math.isfinite(d) and d >= 0 for d in self.disconnects):
            raise BridgeError(
                f"disconnect times must be finite and >= 0 s, got {list(self.disconnects)}"
            )
        self._rng = np.random.default_rng(self.seed)
        self._link = Transport(kind=self.transport, seed=self.seed)

    def arrival_ns(self, send_ns: int) -> int | None:
        """Virtual arrival time of a message sent at ``send_ns``, or None when dropped."""
        # Draw both numbers for every message so a change of drop_prob keeps latencies.
        # Drawn in blocks: the generator's sequence is the same as two draws per message.
        if self._next >= len(self._draws):
            self._draws = self._rng.random(2 * _DRAW_BLOCK).tolist()
            self._next = 0
        u_drop, u_jit = self._draws[self._next], self._draws[self._next + 1]
        self._next += 2
        delay = self.latency_s + self.latency_jitter_s * u_jit
        link = self._link.arrival_ns(int(send_ns))
        arrival = max(self._last_arrival_ns, int(link + round(delay * 1e9)))
        self._last_arrival_ns = arrival
        if u_drop < self.drop_prob:
            return None
        return arrival

    def reset_connection(self, at_ns: int | None = None) -> None:
        """A new TCP connection (made at virtual ``at_ns`` when known): ordering restarts."""
        self._last_arrival_ns = -(2**62)
        self._link.reset(at_ns)


class RenderLoop:
    """Unity's scene: latest arrived pose per topic, applied once per render frame.

    What arrived since the last frame is applied in the frame's ``Update`` (as
    ROS-TCP-Connector's subscriber callbacks run there); the last pose of a topic wins.

    Args:
        topics: topic names rendered (e.g. ``model_rov_pose``, ``gui_camera_pose``).
        unity_map: ROS-TCP-Connector map, ``unity-flu`` (default) or ``unity-enu``.
        frame_rate: render frames per second (``vsync``: the display refresh rate).
        frame_jitter_s: ``fixed``: std of Gaussian jitter on each frame time (clipped to
            +-0.45 of a period, so frame times stay increasing).
        clock_offset_s: Unity clock minus virtual (sim) clock, seconds.
        seed: seed of the frame jitter and stalls.
        frame_model: ``fixed``, ``vsync`` (missed vsyncs with ``stall_prob`` per frame) or
            ``trace`` (frame durations replayed from ``frame_trace``), see
            :class:`uwval.bridge.unity_model.FrameClock`.
        stall_prob: ``vsync``: probability that a frame misses its vsync.
        frame_trace: ``trace``: file of frame durations (s), one per line.
        float32: store poses as a Unity Transform does (float32 position and rotation).
        clock_drift_ppm: Unity's clock runs fast by this many parts per million of the
            time since the first frame (negative: slow).
    """

    def __init__(
        self,
        topics: Sequence[str],
        *,
        unity_map: str = "unity-flu",
        frame_rate: float = 60.0,
        frame_jitter_s: float = 0.0,
        clock_offset_s: float = 0.0,
        seed: int = 0,
        frame_model: str = "fixed",
        stall_prob: float = 0.005,
        frame_trace: str | None = None,
        float32: bool = False,
        clock_drift_ppm: float = 0.0,
    ) -> None:
        # Written as ``not (ok)`` so that NaN fails too; an infinite rate never advances.
        if not (0 < frame_rate < math.inf):
            raise BridgeError(f"frame rate must be finite and positive, got {frame_rate}")
        if not (0 <= frame_jitter_s < math.inf):
            raise BridgeError(f"frame jitter must be finite and >= 0 s, got {frame_jitter_s}")
        if not math.isfinite(clock_offset_s):
            raise BridgeError(f"Unity clock offset must be finite, got {clock_offset_s} s")
        if not (math.isfinite(clock_drift_ppm) and abs(clock_drift_ppm) < 1e5):
            raise BridgeError(
                f"Unity clock drift must be a finite number of ppm below 1e5 in size, "
                f"got {clock_drift_ppm}"
            )
        conv = get_convention(unity_map)
        if not (conv.name.startswith("unity") or unity_map.lower() == "unity-ruf"):
            raise BridgeError(
                f"{unity_map!r} is not a Unity map; use unity-flu, unity-enu, "
                "unity-enu-south|west, unity-frd (= unity-ned), unity-ned-east|south|west "
                "or unity-ruf"
            )
        self.unity_map = conv.name
        self.topics = list(topics)
        self.frame_rate = float(frame_rate)
        self.frame_jitter_s = float(frame_jitter_s)
        self.offset_ns = round(clock_offset_s * 1e9)
        self.drift = float(clock_drift_ppm) * 1e-6
        self.float32 = bool(float32)
        self.clock = FrameClock(
            kind=frame_model,
            rate_hz=self.frame_rate,
            stall_prob=stall_prob,
            trace=read_frame_trace(frame_trace) if frame_trace is not None else None,
            jitter_s=self.frame_jitter_s,
            seed=seed,
        )
        self._first_frame_ns: int | None = None
        # Per topic: pending (arrival_ns, stamp, pos_u, quat_u) in arrival order, and current.
        self._pending: dict[str, list[tuple[int, int, F64, F64]]] = {t: [] for t in topics}
        self._current: dict[str, tuple[int, F64, F64]] = {}

    def frame_times(self, start_ns: int, end_ns: int) -> Iterator[int]:
        """Virtual render-frame times in [start_ns, end_ns] under the frame model."""
        self._first_frame_ns = int(start_ns)
        return self.clock.times(start_ns, end_ns)

    def unity_time_ns(self, frame_ns: int) -> int:
        """Unity's clock at virtual time ``frame_ns``: offset plus drift since the first frame."""
        first = self._first_frame_ns if self._first_frame_ns is not None else frame_ns
        return frame_ns + self.offset_ns + round(self.drift * (frame_ns - first))

    def arrive(self, pose: ReceivedPose, arrival_ns: int) -> None:
        """A pose reached Unity (virtual ``arrival_ns``): convert it into Unity axes now."""
        self.arrive_many([pose], [arrival_ns])

    def arrive_many(self, poses: Sequence[ReceivedPose], arrivals_ns: Sequence[int]) -> None:
        """Several poses reached Unity, in arrival order; converted in one vectorised call."""
        if not poses:
            return
        pos_u, quat_u = convert_arrays(
            np.array([p.position for p in poses]),
            np.array([p.orientation for p in poses]),
            "enu",
            self.unity_map,
        )
        if self.float32:
            pos_u, quat_u = float32_transform(pos_u, quat_u)
        for k, (pose, arrival) in enumerate(zip(poses, arrivals_ns, strict=True)):
            self._pending.setdefault(pose.topic, []).append(
                (int(arrival), pose.stamp_ns, pos_u[k], quat_u[k])
            )

    def discard_after(self, t_ns: int) -> int:
        """Forget poses arriving after ``t_ns`` (in flight when the connection dropped)."""
        lost = 0
        for pending in self._pending.values():
            keep = [p for p in pending if p[0] <= t_ns]
            lost += len(pending) - len(keep)
            pending[:] = keep
        return lost

    def render(self, frame_ns: int) -> list[AppliedTransform]:
        """Apply, per topic, the latest pose arrived by ``frame_ns``; one transform each."""
        out = []
        for topic in self.topics:
            pending = self._pending.get(topic, [])
            n = 0
            while n < len(pending) and pending[n][0] <= frame_ns:
                n += 1
            if n:
                _, stamp, pos, quat = pending[n - 1]
                self._current[topic] = (stamp, pos, quat)
                del pending[:n]
            cur = self._current.get(topic)
            if cur is None:
                continue  # nothing received yet: Unity shows the scene's initial pose
            out.append(
                AppliedTransform(
                    topic, self.unity_time_ns(frame_ns), frame_ns, cur[1], cur[2], cur[0]
                )
            )
        return out


def decode_pose_frame(
    frame: wire.Frame, protocol: wire.Protocol, recv_ns: int | None = None
) -> ReceivedPose:
    """A received topic frame holding a PoseStamped -> :class:`ReceivedPose`; ``recv_ns``
    (``time.monotonic_ns()`` clock) when it was read, default now."""
    t_ns, pos, quat, fid = wire.decode_pose_stamped(frame.payload, protocol)
    when = time.monotonic_ns() if recv_ns is None else recv_ns
    return ReceivedPose(frame.destination, t_ns, pos, quat, fid, when)


class SocketPort:
    """The Connector reader's port on a real socket and the wall clock: frames read are
    queued with their read time for the render loop (thread-safe hand-off, as the
    Connector's ``ConcurrentQueue``)."""

    def __init__(self, connection: UnityConnection) -> None:
        self.connection = connection
        self.queue: deque[tuple[wire.Frame, int]] = deque()
        #: Why the reader stopped (a lost link), or "".
        self.error = ""

    def now_ns(self) -> int:
        return time.monotonic_ns()

    def sleep_ns(self, ns: int) -> None:
        wall_sleep_ns(ns)

    def read_available(self, now_ns: int) -> bool:
        conn = self.connection
        if not conn.has_pending and not conn.receive(0.0):
            return False
        for f in conn.take_frames():
            self.queue.append((f, now_ns))
        return True


class ReaderThread:
    """ROS-TCP-Connector's background reader on a thread, for one connection."""

    def __init__(self, connection: UnityConnection, reader: ConnectorReader) -> None:
        self.port = SocketPort(connection)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, args=(reader,), daemon=True)
        self._thread.start()

    def _run(self, reader: ConnectorReader) -> None:
        try:
            reader.run(self.port, 2**62, self._stop.is_set)
        except BridgeError as exc:  # a lost link: the render loop reconnects
            self.port.error = str(exc) or "connection lost"

    @property
    def failed(self) -> bool:
        """True when the reader stopped on a lost link (see ``port.error``)."""
        return bool(self.port.error)

    def take(self) -> list[tuple[wire.Frame, int]]:
        """Frames read since the last call, with their read times (ns, monotonic)."""
        q = self.port.queue
        return [q.popleft() for _ in range(len(q))]

    def stop(self) -> None:
        """Stop the reader (it notices within one idle sleep) and wait for it."""
        self._stop.set()
        self._thread.join(5.0)


class UnityClient:
    """A Unity-like client on the wall clock: connect, render at a frame rate, reconnect.

    Used against a live endpoint (``uwval bridge serve`` or ``replay``). A background reader
    drains the socket as ROS-TCP-Connector's does (10 ms idle sleep,
    :mod:`uwval.bridge.connector_reader`); each frame ``Update`` takes what it queued,
    applies the latest pose per topic and hands every
    :class:`AppliedTransform` to ``on_frame``; on a lost connection it waits
    ``reconnect_delay_s`` and reconnects, re-registering its subscriptions as Unity does.
    Latency, drops and link drops (``faults.disconnects``, seconds after the start) come
    from ``faults``, on the wall clock.
    """

    def __init__(
        self,
        host: str = wire.DEFAULT_HOST,
        port: int = wire.DEFAULT_PORT,
        *,
        topics: Sequence[str] = ("model_rov_pose", "gui_camera_pose"),
        unity_map: str = "unity-flu",
        frame_rate: float = 60.0,
        clock_offset_s: float = 0.0,
        protocol: wire.Protocol | Literal["auto"] = "ROS2",
        faults: FaultModel | None = None,
        reconnect_delay_s: float = RECONNECT_DELAY_S,
        seed: int = 0,
        clock: Literal["monotonic", "epoch"] = "monotonic",
        on_message: Callable[[str, str], None] | None = None,
    ) -> None:
        if clock not in ("monotonic", "epoch"):
            raise BridgeError(f"Unity clock must be monotonic or epoch, got {clock!r}")
        self.connection = UnityConnection(
            host,
            port,
            subscriptions={t: wire.POSE_STAMPED for t in topics},
            protocol=protocol,
            on_message=on_message,
        )
        self.scene = RenderLoop(
            topics,
            unity_map=unity_map,
            frame_rate=frame_rate,
            clock_offset_s=clock_offset_s,
            seed=seed,
        )
        self.faults = faults or FaultModel(seed=seed)
        self.reconnect_delay_s = reconnect_delay_s
        #: ``time.time_ns() - time.monotonic_ns()`` measured once when the client is made,
        #: ns: maps the monotonic receive/frame times to Unix epoch time.
        self.epoch_minus_monotonic_ns = epoch_minus_monotonic_ns()
        #: ``epoch``: Unity transforms are stamped on the Unix epoch (wall) clock, like ROS
        #: header stamps (monotonic frame time + :attr:`epoch_minus_monotonic_ns`, so steady);
        #: ``monotonic``: on ``time.monotonic_ns()`` (seconds since boot). Plus clock_offset_s.
        self.clock = clock
        if clock == "epoch":
            self.scene.offset_ns += self.epoch_minus_monotonic_ns
        #: Called with each pose as it is handed to Update (e.g. to record the Gazebo side).
        self.on_receive: Callable[[ReceivedPose], None] | None = None
        #: The Connector's background reader (10 ms idle sleep), one thread per connection.
        self.reader = ConnectorReader(seed=seed)
        self._reader: ReaderThread | None = None
        self._next_connect = 0
        self.received = 0
        self.dropped = 0
        self.disconnects = 0
        #: The last connect/link error (why the client is not connected), or "".
        self.last_error = ""

    @property
    def protocol(self) -> wire.Protocol:
        """The protocol in use (after an ``auto`` connect: the endpoint's)."""
        return self.connection.protocol

    def run_realtime(
        self,
        duration_s: float,
        on_frame: Callable[[AppliedTransform], None] | None = None,
        connect_timeout: float = 5.0,
        stop: threading.Event | None = None,
    ) -> list[AppliedTransform]:
        """Run the render loop for ``duration_s`` wall seconds (or until ``stop`` is set);
        returns the applied transforms."""
        applied: list[AppliedTransform] = []
        t0 = time.monotonic_ns()
        end = t0 + int(duration_s * 1e9)
        self._next_connect = t0
        # Injected link drops, on the wall clock since the start of the run.
        drops = sorted(t0 + int(d * 1e9) for d in self.faults.disconnects)
        try:
            for frame_ns in self.scene.frame_times(t0, end):
                if stop is not None and stop.is_set():
                    break
                now = time.monotonic_ns()
                if frame_ns > now:
                    time.sleep((frame_ns - now) * 1e-9)
                while drops and drops[0] <= time.monotonic_ns():
                    drops.pop(0)
                    if self._reader is not None:
                        self._drop_link("")
                        self.scene.discard_after(time.monotonic_ns())
                # the reader thread may have closed the socket: it says why, _update reconnects
                if self._reader is None and time.monotonic_ns() >= self._next_connect:
                    self._connect(connect_timeout)
                if self._reader is not None:
                    self._update()
                for tr in self.scene.render(time.monotonic_ns()):
                    applied.append(tr)
                    if on_frame is not None:
                        on_frame(tr)
        finally:
            if self._reader is not None:
                self._reader.stop()
                self._reader = None
            self.connection.close()
        return applied

    def _connect(self, timeout: float) -> None:
        """(Re)connect and start the Connector's reader thread; on failure retry later."""
        try:
            self.connection.connect(timeout)
            self.faults.reset_connection()
        except ProtocolMismatchError:
            self.connection.close()
            raise  # a setting to change, not a link to retry
        except BridgeError as exc:
            self.last_error = str(exc)
            self._next_connect = time.monotonic_ns() + int(self.reconnect_delay_s * 1e9)
            return
        self._reader = ReaderThread(self.connection, self.reader)

    def _drop_link(self, why: str) -> None:
        """Close the link (lost, or an injected drop) and reconnect after the delay."""
        if why:
            self.last_error = why
        if self._reader is not None:
            self._reader.stop()
            self._reader = None
        self.connection.close()
        self.disconnects += 1
        self._next_connect = time.monotonic_ns() + int(self.reconnect_delay_s * 1e9)

    def _update(self) -> None:
        """Unity's ``Update``: hand what the reader queued to the scene, keep the link alive."""
        reader = self._reader
        assert reader is not None
        try:
            for f, read_ns in reader.take():
                self.received += 1
                pose = decode_pose_frame(f, self.protocol, read_ns)
                if self.on_receive is not None:
                    self.on_receive(pose)
                arr = self.faults.arrival_ns(pose.recv_wall_ns)
                if arr is None:
                    self.dropped += 1
                else:
                    self.scene.arrive(pose, arr)
            if reader.failed:
                raise BridgeError(reader.port.error)
            self.connection.keepalive_if_idle()
        except BridgeError as exc:  # lost link or a malformed frame: reconnect
            self._drop_link(str(exc))
