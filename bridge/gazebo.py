"""The Gazebo side of the bridge: pose ticks and a publisher that feeds the endpoint.

In a real setup ros_gz_bridge turns Gazebo's ``/model/<name>/pose`` into ROS
``geometry_msgs/PoseStamped`` topics stamped with sim time, and ROS-TCP-Endpoint forwards
them to Unity. :class:`GazeboPublisher` plays that part in-process: each tick's poses (ENU
world, FLU body) become PoseStamped bodies (``frame_id`` ``"world"``) published on
``model_rov_pose`` and ``gui_camera_pose``.
"""

from __future__ import annotations

import struct
import time
from collections.abc import Callable, Iterable, Iterator, Sequence
from typing import Any, Literal, Protocol

import numpy as np
from numpy.typing import NDArray

from uwval.bridge import protocol as wire
from uwval.bridge.errors import BridgeError
from uwval.bridge.options import CAMERA_TOPIC, DEFAULT_TOPICS, VEHICLE_TOPIC
from uwval.bridge.server import BridgeServer
from uwval.frames import convert_arrays, get_convention
from uwval.posestream import PoseStream

F64 = NDArray[np.float64]
#: One publish tick: (sim time ns, {topic name: (position (3,), quaternion xyzw (4,))}).
Tick = tuple[int, dict[str, tuple[F64, F64]]]


_STAMP_CDR = struct.Struct("<4siII")  # encapsulation, sec, nanosec, len(frame_id + NUL)
_STAMP_ROS1 = struct.Struct("<IIII")  # seq, secs, nsecs, len(frame_id)
_POSE = struct.Struct("<7d")


class PoseEncoder:
    """PoseStamped bodies of one ``frame_id`` in one protocol, per message at little cost.

    The bytes around the stamp and the pose are built once; each message packs its stamp
    and seven doubles into them. Byte-identical to :func:`uwval.bridge.protocol.
    encode_pose_stamped` (and so to rosbags' serializers; tests compare them).
    """

    def __init__(self, frame_id: str, protocol: wire.Protocol = "ROS2") -> None:
        self.frame_id = frame_id
        self.protocol = protocol
        fid = frame_id.encode("utf-8")
        self._len = len(fid) + 1 if protocol == "ROS2" else len(fid)
        if protocol == "ROS2":
            head = 12 + len(fid) + 1  # stamp, length, frame_id and its NUL
            self._mid = fid + b"\x00" + b"\x00" * (-head % 8)
        else:
            self._mid = fid

    def encode(self, t_ns: int, position: Any, quat: Any, seq: int = 0) -> bytes:
        """One body: header stamp ``t_ns`` (ns), position (3,) m, quaternion (4,) x y z w."""
        sec, nsec = divmod(int(t_ns), 1_000_000_000)
        p = position.tolist() if hasattr(position, "tolist") else list(position)
        q = quat.tolist() if hasattr(quat, "tolist") else list(quat)
        if len(p) != 3 or len(q) != 4:
            return wire.encode_pose_stamped(
                t_ns, position, quat, self.frame_id, self.protocol, seq=seq
            )  # shapes it does not take: the reference encoder says what is wrong
        body = _POSE.pack(p[0], p[1], p[2], q[0], q[1], q[2], q[3])
        if self.protocol == "ROS2":
            return _STAMP_CDR.pack(wire.CDR_HEADER, sec, nsec, self._len) + self._mid + body
        if sec < 0:
            raise wire.ProtocolError(f"ROS 1 time cannot be negative (t_ns={t_ns})")
        return _STAMP_ROS1.pack(seq & 0xFFFFFFFF, sec, nsec, self._len) + self._mid + body


class GazeboPublisher:
    """Publish pose ticks into a :class:`BridgeServer` as ros_gz_bridge would."""

    def __init__(
        self,
        server: BridgeServer,
        *,
        topics: Sequence[str] = DEFAULT_TOPICS,
        frame_id: str = "world",
    ) -> None:
        self.server = server
        self.protocol = server.protocol
        self.frame_id = frame_id
        self.topics = list(topics)
        self.seq = 0
        self._encoder = PoseEncoder(frame_id, self.protocol)
        for t in self.topics:
            server.advertise(t, wire.POSE_STAMPED)

    def encode(self, t_ns: int, position: F64, quat: F64) -> bytes:
        """One PoseStamped body in the server's protocol."""
        return self._encoder.encode(t_ns, position, quat, seq=self.seq)

    def publish(self, topic: str, t_ns: int, position: F64, quat: F64) -> int:
        """Publish one pose; returns how many clients it was queued to."""
        self.seq += 1
        return self.server.publish(topic, self.encode(t_ns, position, quat))

    def publish_tick(self, tick: Tick) -> dict[str, int]:
        """Publish every pose of a tick; returns clients reached per topic."""
        t_ns, poses = tick
        return {name: self.publish(name, t_ns, p, q) for name, (p, q) in poses.items()}


class EndpointPublisher:
    """Publish pose ticks INTO a running ROS-TCP endpoint, as a ROS publisher.

    Connects to the endpoint (Unity's ROS-TCP-Endpoint or ``uwval bridge serve``) as a
    client, registers each topic with ``__publish`` (``geometry_msgs/PoseStamped``) and sends
    PoseStamped bodies (ENU world / FLU body, ``frame_id`` ``"world"``, header stamp = the
    tick's time in ns) in the protocol the endpoint's handshake announces (``protocol="auto"``).
    The endpoint republishes them in the ROS graph, so ROS nodes (rospy, rclpy) receive them.
    Same interface as :class:`GazeboPublisher` (``publish``, ``publish_tick``, ``seq``).

    Args:
        host, port: the endpoint.
        topics: tick name -> ROS topic (default: each of ``DEFAULT_TOPICS`` as it is,
            relative, which ROS resolves in the endpoint's namespace, e.g. ``/model_rov_pose``).
        on_message: called with (``__log``/``__warn``/``__error``, text) from the endpoint.
    """

    def __init__(
        self,
        host: str,
        port: int,
        *,
        topics: dict[str, str] | None = None,
        frame_id: str = "world",
        protocol: wire.Protocol | Literal["auto"] = "auto",
        connect_timeout: float = 5.0,
        on_message: Callable[[str, str], None] | None = None,
    ) -> None:
        from uwval.bridge.unity_client import UnityConnection

        self.topics = dict(topics) if topics else {t: t for t in DEFAULT_TOPICS}
        self.frame_id = frame_id
        self.seq = 0
        self.connection = UnityConnection(
            host,
            port,
            publications={t: wire.POSE_STAMPED for t in self.topics.values()},
            protocol=protocol,
            on_message=on_message,
        )
        self.connection.connect(connect_timeout)
        self.protocol: wire.Protocol = self.connection.protocol
        self._encoder = PoseEncoder(frame_id, self.protocol)

    def publish(self, topic: str, t_ns: int, position: F64, quat: F64) -> int:
        """Send one pose (``topic`` is a tick name); returns 1 (one endpoint)."""
        self.seq += 1
        body = self._encoder.encode(t_ns, position, quat, seq=self.seq)
        self.connection.publish(self.topics.get(topic, topic), body)
        return 1

    def publish_tick(self, tick: Tick) -> dict[str, int]:
        """Send every pose of a tick, then read what the endpoint sent (logs, errors)."""
        t_ns, poses = tick
        out = {name: self.publish(name, t_ns, p, q) for name, (p, q) in poses.items()}
        self.service()
        return out

    def service(self) -> None:
        """Read what the endpoint sent without waiting (its ``__log``/``__error`` reach
        ``on_message``; echoed topic messages are discarded) and keep the link alive."""
        while True:
            self.connection.poll(0.0)
            if not self.connection.has_pending:
                break
        self.connection.keepalive_if_idle()

    def close(self) -> None:
        """Close the connection to the endpoint."""
        self.connection.close()


def paced(ticks: Iterable[Tick], speed: float, start_ns: int | None = None) -> Iterator[Tick]:
    """Yield ``ticks`` at their wall-clock due times: tick ``t`` at ``start_ns + (t -
    t_first) / speed`` on the ``time.monotonic_ns()`` clock (default start: now). ``speed``
    0 or infinite: as fast as possible."""
    fast = speed == 0 or speed == float("inf")
    start = time.monotonic_ns() if start_ns is None else start_ns
    t_first: int | None = None
    for tick in ticks:
        if t_first is None:
            t_first = tick[0]
        if not fast:
            lag = ((tick[0] - t_first) / speed - (time.monotonic_ns() - start)) * 1e-9
            if lag > 0:
                time.sleep(lag)
        yield tick


def publish_ticks_realtime(
    ticks: Iterable[Tick],
    publisher: EndpointPublisher | GazeboPublisher,
    *,
    speed: float = 1.0,
    writer: Any = None,
    start_delay_s: float = 0.0,
    start_at_ns: int | None = None,
) -> int:
    """Publish precomputed ticks paced to the wall clock, recording each on ``writer``
    (``/gazebo/<name>``, frame ``world``) when given; returns the ticks sent.

    The first tick goes out at ``start_at_ns`` (``time.monotonic_ns()`` clock; default now +
    ``start_delay_s``), tick ``t`` at ``start + (t - t_first) / speed``; ``speed`` 0: as fast
    as possible. Until the start the endpoint is read (logs, errors): a ROS 1 subscriber needs a
    moment to connect to the endpoint's new publisher, and ROS 1 drops what is published
    before it has.
    """
    start = time.monotonic_ns() + round(start_delay_s * 1e9) if start_at_ns is None else start_at_ns
    service = getattr(publisher, "service", None)
    while time.monotonic_ns() < start:
        if service is not None:
            service()
        time.sleep(min(0.01, max(0.0, (start - time.monotonic_ns()) * 1e-9)))
    sent = 0
    for tick in paced(ticks, speed, start):
        t_ns, poses = tick
        publisher.publish_tick(tick)
        sent += 1
        if writer is not None:
            for name, (p, q) in poses.items():
                writer.write_pose(f"/gazebo/{name}", t_ns, p, q, publisher.frame_id)
    return sent


class LiveSimulator(Protocol):
    """What :func:`run_live` steps (``uwval.simulator.Simulator``; the bridge does not import
    the simulator)."""

    def advance_to(self, t_ns: int) -> list[tuple[int, F64, F64, F64, F64]]: ...


def run_live(
    sim: LiveSimulator,
    publisher: GazeboPublisher | EndpointPublisher,
    *,
    publish_rate: float,
    duration_s: float = 0.0,
    speed: float = 1.0,
    control: Callable[[int], bool] | None = None,
    writer: Any = None,
    on_tick: Callable[[int, F64, F64], None] | None = None,
) -> int:
    """Drive a live simulator on the wall clock and publish its ticks (``uwval teleop``).

    Every publish period (``1 / publish_rate`` s of sim time) ``control(t_ns)`` runs first
    (keyboard input; False stops the run), then the simulator advances to ``t_ns`` and each
    tick crossed is published (vehicle and camera, ENU/FLU), recorded on ``writer``
    (``/gazebo/<topic>``, frame ``world``) when given, and handed to ``on_tick(t_ns,
    position, quat)``. ``speed`` is sim seconds per wall second (0: as fast as possible);
    ``duration_s`` 0 runs until ``control`` stops it. Returns the ticks published.
    """
    period_ns = round(1e9 / publish_rate)
    t_wall0 = time.perf_counter()
    sent = 0
    t_ns = 0
    while duration_s <= 0 or t_ns <= int(duration_s * 1e9):
        if control is not None and not control(t_ns):
            break
        for tick_t, vp, vq, cp, cq in sim.advance_to(t_ns):
            publisher.publish_tick((tick_t, {VEHICLE_TOPIC: (vp, vq), CAMERA_TOPIC: (cp, cq)}))
            sent += 1
            if writer is not None:
                writer.write_pose(f"/gazebo/{VEHICLE_TOPIC}", tick_t, vp, vq, publisher.frame_id)
                writer.write_pose(f"/gazebo/{CAMERA_TOPIC}", tick_t, cp, cq, publisher.frame_id)
            if on_tick is not None:
                on_tick(tick_t, vp, vq)
        t_ns += period_ns
        if speed > 0:  # pace sim time to the wall clock
            lag = t_ns * 1e-9 / speed - (time.perf_counter() - t_wall0)
            if lag > 0:
                time.sleep(lag)
    return sent


def ticks_from_streams(*streams: PoseStream, names: Sequence[str] | None = None) -> Iterator[Tick]:
    """Turn simulator PoseStreams (vehicle, camera, ...) into publish ticks, in time order.

    ``names`` default to ``model_rov_pose``, ``gui_camera_pose`` for the first two streams
    (or the stream's topic basename beyond those). Streams in another convention are
    converted to ENU/FLU first. A tick holds every stream that has a sample at that stamp.
    """
    if not streams:
        raise BridgeError("ticks_from_streams needs at least one pose stream")
    if names is None:
        names = [
            DEFAULT_TOPICS[i]
            if i < len(DEFAULT_TOPICS)
            else (s.topic.strip("/").split("/")[-1] or f"pose_{i}")
            for i, s in enumerate(streams)
        ]
    if len(names) != len(streams):
        raise BridgeError(f"{len(names)} names for {len(streams)} streams")
    enu = []
    for s in streams:
        if get_convention(s.frame).name != "enu":
            pos, quat = convert_arrays(s.position, s.orientation, s.frame, "enu")
            enu.append((s.t, pos, quat))
        else:
            enu.append((s.t, s.position, s.orientation))
    times = np.unique(np.concatenate([e[0] for e in enu]))
    # index of each stream's sample at each tick time, or -1
    idx = []
    for t, _, _ in enu:
        i = np.searchsorted(t, times)
        ok = (i < len(t)) & (t[np.minimum(i, len(t) - 1)] == times)
        idx.append(np.where(ok, i, -1))
    for k in range(len(times)):
        poses = {}
        for name, (_, pos, quat), ii in zip(names, enu, idx, strict=True):
            j = int(ii[k])
            if j >= 0:
                poses[name] = (pos[j], quat[j])
        yield int(times[k]), poses
