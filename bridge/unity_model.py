"""How a real Unity scene behind ROS-TCP-Connector stores, renders and receives poses.

Models used by the Unity-like client (:class:`uwval.bridge.unity_client.RenderLoop` and
:class:`~uwval.bridge.unity_client.FaultModel`) so that the "Unity" stream carries what a
real Unity would add to the Gazebo pose. Every model is seeded and runs on the session's
virtual clock (ns). Which real behaviour each models, and where its numbers come from:

- :func:`float32_transform`: Unity's ``Transform`` keeps ``localPosition`` (``Vector3``) and
  ``localRotation`` (``Quaternion``) as C# ``float`` (IEEE float32). A pose written into a
  Transform is rounded to float32: at 1 km from the origin the spacing of float32 is
  2^-14 m = 6.1e-5 m, at the origin it is below 1e-7 m for any sub-metre value.
- :class:`FrameClock`: when Unity renders a frame. ``fixed``: every 1/rate s (a capped
  ``Application.targetFrameRate`` with no misses). ``vsync``: frames on the display's vsync
  grid (``QualitySettings.vSyncCount = 1``); a frame that misses its vsync (GC, asset load,
  a slow frame) shows one to three refresh periods late (``stall_prob`` per frame, default
  0.5 %: a few visible hitches per minute at 60 Hz). ``trace``: frame durations measured
  from a real Unity (one ``Time.unscaledDeltaTime`` per line, seconds), replayed in a loop.
- ROS-TCP-Connector's ``ROSConnection`` receives on a socket thread and hands messages to
  the subscribers' callbacks in ``Update``: what arrived since the last frame is applied at
  the frame, the last pose of a topic wins (RenderLoop.render).
- :class:`Transport`: when a message published by the endpoint reaches Unity.
  ``ideal``: at once (only the FaultModel's latency options). ``nodelay``: an endpoint
  that sets TCP_NODELAY (uwval's own): loopback wire time, lognormal, median 0.1 ms, p99
  about 0.25 ms. ``real-endpoint``: Unity's ROS-TCP-Endpoint 0.7.0 (Python): it does not set
  TCP_NODELAY, so Nagle's algorithm holds a small write while an earlier segment is not yet
  acknowledged; Unity's client sends a keepalive after 1 s without sending, and a receiver
  that has just sent data enters Linux's delayed-ACK ("pingpong") mode, so the next segment
  is acknowledged only when the delayed-ACK timer fires (TCP_ATO_MIN = 40 ms) and every
  pose written meanwhile waits for it. Per message the endpoint's own handling (rospy /
  rclpy callback, serialisation, a thread hop) takes a lognormal time of median 0.57 ms.
  Calibrated on the real ROS-TCP-Endpoint 0.7.0 (ROS 1, loopback, 50 Hz, 20 s, socket
  arrival minus send; docs/bridge.md): one topic p50 0.69 ms, p99 20.8 ms (model 0.69 /
  20.9); two topics per tick, first p50 0.84 / p99 21.9, second 0.80 / 41.7 ms (model
  0.68 / 20.9 and 0.92 / 40.9): the second pose of a tick waits for the first one's
  delayed ACK. Without keepalives about 1.0 ms p99.
- :class:`uwval.bridge.connector_reader.ConnectorReader`: what happens after the socket
  (the Connector's reader task and its 10 ms idle sleep, then ``Update``).
- Clock offset and drift: Unity stamps with its own clock,
  ``unity_t = t + offset + drift_ppm * 1e-6 * (t - t_start)``; a quartz clock drifts by
  some 10-50 ppm.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from uwval.bridge.errors import BridgeError

F64 = NDArray[np.float64]

FRAME_MODELS = ("fixed", "vsync", "trace")
TRANSPORTS = ("ideal", "nodelay", "real-endpoint")

#: Linux's minimum delayed-ACK timeout (include/net/tcp.h ``TCP_ATO_MIN = HZ / 25``), ns.
DELAYED_ACK_NS = 40_000_000
#: Unity's ROSConnection sends a keepalive after this long without sending, ns.
KEEPALIVE_NS = 1_000_000_000


def float32_transform(position: F64, orientation: F64) -> tuple[F64, F64]:
    """A pose (m; quaternion x y z w) as a Unity ``Transform`` stores it: float32 values.

    Returned as float64 arrays holding float32 values (what ``transform.position`` reads
    back). Shapes are kept: (..., 3) and (..., 4).
    """
    pos = np.asarray(position, dtype=np.float64).astype(np.float32).astype(np.float64)
    quat = np.asarray(orientation, dtype=np.float64).astype(np.float32).astype(np.float64)
    return pos, quat


def read_frame_trace(path: str | Path) -> F64:
    """Frame durations (s) from a text file: one per line; blank lines and ``#`` comments
    skipped; a CSV line takes its last field. Every duration must be finite and > 0."""
    p = Path(path)
    try:
        text = p.read_text()
    except (OSError, UnicodeDecodeError) as exc:
        raise BridgeError(f"frame trace {p}: cannot read it: {exc}") from None
    vals: list[float] = []
    for i, line in enumerate(text.splitlines(), 1):
        s = line.split("#", 1)[0].strip()
        if not s:
            continue
        field_ = s.split(",")[-1].strip()
        try:
            v = float(field_)
        except ValueError:
            raise BridgeError(
                f"frame trace {p} line {i}: {field_!r} is not a frame duration in seconds"
            ) from None
        if not (math.isfinite(v) and v > 0):
            raise BridgeError(f"frame trace {p} line {i}: frame duration must be > 0 s, got {v}")
        vals.append(v)
    if not vals:
        raise BridgeError(f"frame trace {p}: no frame durations in it")
    return np.array(vals)


@dataclass
class FrameClock:
    """Virtual render-frame times of one run (see the module doc for the kinds).

    Args:
        kind: ``fixed``, ``vsync`` or ``trace``.
        rate_hz: frame rate (fixed) or display refresh rate (vsync).
        stall_prob: vsync: probability that a frame misses its vsync.
        max_stall_frames: vsync: a stalled frame shows 1..max refresh periods late.
        trace: frame durations (s) replayed by ``trace``.
        jitter_s: fixed: std of Gaussian jitter per frame (clipped to +-0.45 period).
        seed: seeds stalls and jitter.
    """

    kind: str = "vsync"
    rate_hz: float = 60.0
    stall_prob: float = 0.005
    max_stall_frames: int = 3
    trace: F64 | None = None
    jitter_s: float = 0.0
    seed: int = 0
    _rng: np.random.Generator = field(init=False, repr=False)

    def __post_init__(self) -> None:
        if self.kind not in FRAME_MODELS:
            raise BridgeError(f"frame model {self.kind!r}: choose one of {', '.join(FRAME_MODELS)}")
        if not (0 < self.rate_hz < math.inf):
            raise BridgeError(f"frame rate must be finite and positive, got {self.rate_hz}")
        if not 0.0 <= self.stall_prob < 1.0:
            raise BridgeError(f"frame stall probability must be in [0, 1), got {self.stall_prob}")
        if self.max_stall_frames < 1:
            raise BridgeError(f"max stall frames must be >= 1, got {self.max_stall_frames}")
        if not (0 <= self.jitter_s < math.inf):
            raise BridgeError(f"frame jitter must be finite and >= 0 s, got {self.jitter_s}")
        if self.kind == "trace" and (self.trace is None or len(self.trace) == 0):
            raise BridgeError("frame model 'trace' needs a frame trace file")
        self._rng = np.random.default_rng([self.seed, 1])

    def times(self, start_ns: int, end_ns: int) -> Iterator[int]:
        """Frame times (ns, increasing) in [start_ns, end_ns]."""
        period = 1.0 / self.rate_hz
        if self.kind == "fixed":
            k = 0
            while True:
                nominal = start_ns + round(k * period * 1e9)
                if nominal > end_ns:
                    return
                jit = 0.0
                if self.jitter_s > 0:
                    jit = float(
                        np.clip(self._rng.normal(0.0, self.jitter_s), -0.45 * period, 0.45 * period)
                    )
                yield max(start_ns, nominal + round(jit * 1e9))
                k += 1
        elif self.kind == "vsync":
            # The display's vsync grid does not know Gazebo's publish grid: its phase is
            # drawn per seed (a real replicate differs there first).
            start_ns += int(self._rng.integers(0, round(period * 1e9)))
            vsync = 0  # index of the vsync the frame is shown at
            while True:
                t = start_ns + round(vsync * period * 1e9)
                if t > end_ns:
                    return
                yield t
                late = 0
                if self._rng.random() < self.stall_prob:
                    late = int(self._rng.integers(1, self.max_stall_frames + 1))
                vsync += 1 + late
        else:
            assert self.trace is not None
            durations = np.round(self.trace * 1e9).astype(np.int64)
            t, i = start_ns, 0
            while t <= end_ns:
                yield t
                t += int(durations[i % durations.size])
                i += 1


@dataclass
class Transport:
    """Arrival times of the endpoint's messages at Unity (see the module doc for the kinds).

    Call :meth:`arrival_ns` once per message, in the order the endpoint sends them, with
    the virtual time (ns) it was published. Units: ns; ``*_ms`` parameters in ms.

    Args:
        kind: ``ideal``, ``nodelay`` or ``real-endpoint``.
        wire_median_ms, wire_sigma: lognormal one-way loopback time (each direction).
        endpoint_median_ms, endpoint_sigma: real-endpoint: lognormal handling time per
            message inside ROS-TCP-Endpoint before its socket write.
        keepalives: real-endpoint: Unity sends keepalives (1 s idle), which put its TCP
            receiver into delayed-ACK mode.
        seed: seeds the random times.
    """

    kind: str = "real-endpoint"
    wire_median_ms: float = 0.1
    wire_sigma: float = 0.4
    endpoint_median_ms: float = 0.57
    endpoint_sigma: float = 0.2
    keepalives: bool = True
    seed: int = 0
    _rng: np.random.Generator = field(init=False, repr=False)
    _draws: F64 = field(init=False, repr=False)
    _next: int = field(default=0, init=False, repr=False)
    _start_ns: int | None = field(default=None, init=False, repr=False)
    _last_write: int = field(default=-(2**62), init=False, repr=False)
    _ack_at: int = field(default=-(2**62), init=False, repr=False)
    _held: tuple[int, int] | None = field(default=None, init=False, repr=False)
    _last_delack_fire: int = field(default=-(2**62), init=False, repr=False)

    def __post_init__(self) -> None:
        if self.kind not in TRANSPORTS:
            raise BridgeError(f"transport {self.kind!r}: choose one of {', '.join(TRANSPORTS)}")
        for name in ("wire_median_ms", "wire_sigma", "endpoint_median_ms", "endpoint_sigma"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0):
                raise BridgeError(f"transport {name} must be finite and >= 0, got {v}")
        self._rng = np.random.default_rng([self.seed, 2])
        self._draws = np.empty(0)

    def reset(self, start_ns: int | None = None) -> None:
        """A new connection (Unity's keepalive phase restarts at ``start_ns``)."""
        self._start_ns = start_ns
        self._last_write = self._ack_at = self._last_delack_fire = -(2**62)
        self._held = None

    def _normal(self) -> float:
        if self._next >= self._draws.size:
            self._draws = self._rng.standard_normal(4096)
            self._next = 0
        v = float(self._draws[self._next])
        self._next += 1
        return v

    def _wire(self) -> int:
        return round(self.wire_median_ms * 1e6 * math.exp(self.wire_sigma * self._normal()))

    def _endpoint(self) -> int:
        return round(self.endpoint_median_ms * 1e6 * math.exp(self.endpoint_sigma * self._normal()))

    def _ack_reaches_sender(self, arrival: int) -> int:
        """When the ACK of a segment that reached Unity at ``arrival`` is back at the
        endpoint: at once, or, in delayed-ACK mode (entered by a keepalive sent since the
        last delayed-ACK timer fired), when the timer fires or the next keepalive carries it."""
        assert self._start_ns is not None
        sent = arrival
        if self.keepalives:
            last_ka = self._start_ns + (arrival - self._start_ns) // KEEPALIVE_NS * KEEPALIVE_NS
            if last_ka > self._last_delack_fire:
                next_ka = last_ka + KEEPALIVE_NS
                sent = min(arrival + DELAYED_ACK_NS, next_ka)
                self._last_delack_fire = sent  # the timer fired: pingpong mode ends
        return sent + self._wire()

    def arrival_ns(self, send_ns: int) -> int:
        """Virtual time (ns) the message published at ``send_ns`` reaches Unity's socket."""
        if self.kind == "ideal":
            return int(send_ns)
        if self._start_ns is None:
            self._start_ns = int(send_ns)
        if self.kind == "nodelay":
            return int(send_ns) + self._wire()
        # real-endpoint: the endpoint writes in order; Nagle holds a write while unacked
        w = max(int(send_ns) + self._endpoint(), self._last_write)
        self._last_write = w
        if self._held is not None and w >= self._ack_at:
            # the held segment left when the ACK came; its own ACK now gates the next
            self._ack_at = self._ack_reaches_sender(self._held[1])
            self._held = None
        if w >= self._ack_at:
            arrival = w + self._wire()
            self._ack_at = self._ack_reaches_sender(arrival)
            return arrival
        if self._held is None:
            self._held = (self._ack_at, self._ack_at + self._wire())
        return self._held[1]
