"""The ROS-TCP endpoint: a TCP server that Unity (ROS-TCP-Connector v0.7) connects to.

It plays ROS-TCP-Endpoint's role. The "ROS side" is in-process: a Gazebo-side publisher
calls :meth:`BridgeServer.publish` as ros_gz_bridge's topics would reach the endpoint's
subscribers, and local callbacks receive what Unity publishes.

Robustness rules (issue 6):
- several clients at once;
- per-client bounded outgoing queue: when full the oldest item is dropped and counted
  (ROS-TCP-Endpoint's queues are unbounded, so overload there shows as growing lag);
- a frame-size cap; a malformed frame closes only that client, with a logged reason;
- a frame is queued atomically (a ``__response`` and its body travel as one item) so a drop
  never splits a pair.

One I/O thread serves every connection (issue 14): non-blocking sockets on a selector
(epoll on Linux), so a connection costs a socket, a parser buffer and a queue, never a
thread. Thread-per-client servers (this one before, and ROS-TCP-Endpoint) keep glibc arenas
and thread stacks after their clients leave; this one holds no per-client thread
(``benchmarks/bridge_hostile.py`` measures its RSS across 10,000 hostile connections; glibc's
malloc_trim is no longer called, nothing native is loaded). A publisher thread sends a
frame itself with a non-blocking send when nothing is queued for that client (no hand-off,
which keeps one-way latency low); what the socket does not take is finished by the I/O
thread. Callbacks (:meth:`BridgeServer.on_topic`) and service handlers run on the I/O thread:
they must not block on the server.

Limits against hostile clients (issue 14), so that memory stays bounded and the accept loop
never dies:
- at most ``max_clients`` connections (default 64). When all are taken, a new connection
  takes the slot of the longest-silent connection that has registered nothing and sent
  nothing for ``EVICT_SILENT_S`` (a socket held open and never used), else of the one that
  has sent nothing but keepalives for longest, if for ``EVICT_SILENT_S`` (registered, then
  idle); otherwise it is closed at once and counted in :attr:`BridgeServer.refused`;
- a connection that sends nothing at all (not a frame, not a keepalive) and registers
  nothing within ``unused_timeout`` (default 10 s) is closed, and so is any connection
  silent (not even a keepalive; ROS-TCP-Connector sends one every second) for
  ``idle_timeout`` (default 5 s);
- a system command's payload is at most ``protocol.MAX_COMMAND_BYTES`` (64 KiB), a frame's
  destination ``MAX_DESTINATION_BYTES`` (1 KiB); a registered topic or message name is at
  most ``MAX_NAME_BYTES`` (1 KiB, a longer topic could never be a frame's destination), and
  a client holds at most ``MAX_REGISTRATIONS`` (256) registrations;
- texts kept in :attr:`BridgeServer.events` are cut to ``EVENT_TEXT_CHARS`` (the newest
  ``EVENTS_KEPT``), and at most ``LOG_BURST`` of them per ``LOG_WINDOW_S`` go to the log (then
  a count of the rest); the statistics of only the last ``CLOSED_STATS_KEPT`` closed clients
  are kept (their subscription lists cut to 16 names of ``CLOSED_NAME_CHARS``), so memory
  comes back when clients leave;
- the listen backlog is the system's ``SOMAXCONN`` (bursts of connections do not wait for
  SYN retries); an accept failure (out of descriptors) pauses accepting for
  ``ACCEPT_BACKOFF_S`` while the connected clients are served, and the loop goes on.

Worst case per connection: the incoming frame buffer (``max_frame``, default 16 MiB, only
while a frame of that size is arriving), the outgoing queue (``queue_size`` frames) and
256 registrations of at most 2 KiB each.

Size: one module on purpose: one class (the endpoint) whose I/O loop, send paths and limits
share its locks and counters; splitting would expose that state.
"""

from __future__ import annotations

import contextlib
import functools
import gc
import itertools
import logging
import selectors
import socket
import struct
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from uwval.bridge import protocol as wire
from uwval.bridge.errors import BridgeError

#: Default bound on simultaneous connections.
DEFAULT_MAX_CLIENTS = 64
#: Default seconds a connection may stay without registering anything.
DEFAULT_UNUSED_TIMEOUT_S = 10.0
#: Default seconds any connection may stay silent (not even a keepalive: ROS-TCP-Connector
#: sends one after 1 s without sending) before it is closed.
DEFAULT_IDLE_TIMEOUT_S = 5.0
#: Seconds of silence after which an unused connection gives its slot to a new one when all
#: ``max_clients`` slots are taken (ROS-TCP-Connector sends a keepalive every second).
EVICT_SILENT_S = 2.0
#: Registrations the endpoint itself holds in ``compat="real-endpoint"`` mode (they outlive
#: connections there, so they are bounded on their own).
MAX_ENDPOINT_REGISTRATIONS = 4096
#: Registrations (subscribe, publish, services) one client may hold.
MAX_REGISTRATIONS = 256
#: Longest topic, service or message name accepted in a registration (bytes of UTF-8).
MAX_NAME_BYTES = wire.MAX_DESTINATION_BYTES
#: Longest text kept in an event (client log texts, names in messages).
EVENT_TEXT_CHARS = 300
#: Server messages logged per ``LOG_WINDOW_S`` at most (the rest are counted, then summarised).
LOG_BURST = 50
LOG_WINDOW_S = 10.0
#: Characters of each topic name kept in a closed client's statistics.
CLOSED_NAME_CHARS = 80
#: Events kept in :attr:`BridgeServer.events` (the newest). Few on purpose: each long-lived
#: small object made during a flood of clients can pin a whole allocator arena.
EVENTS_KEPT = 200
#: Statistics of closed clients kept (the newest).
CLOSED_STATS_KEPT = 64
#: Seconds accepting pauses after an accept failure (e.g. out of file descriptors).
ACCEPT_BACKOFF_S = 0.05

#: Server behaviours: uwval's own (forgiving, several clients) and ROS-TCP-Endpoint 0.7.0's.
COMPAT_MODES = ("uwval", "real-endpoint")
#: Where outgoing frames go: each subscribed client (uwval's), or everything (messages,
#: replies, logs) to the newest connection only, as ROS-TCP-Endpoint 0.7.0's single sender
#: queue does (``compat="real-endpoint"`` only).
ROUTES = ("subscribers", "newest")
#: Message packages a stock ROS install resolves (the real endpoint imports ``pkg.msg``);
#: more with ``known_packages`` or :meth:`BridgeServer.advertise`.
STANDARD_MSG_PACKAGES = frozenset(
    {
        "actionlib_msgs",
        "builtin_interfaces",
        "diagnostic_msgs",
        "geometry_msgs",
        "nav_msgs",
        "rosgraph_msgs",
        "sensor_msgs",
        "shape_msgs",
        "std_msgs",
        "std_srvs",
        "stereo_msgs",
        "tf2_msgs",
        "trajectory_msgs",
        "visualization_msgs",
    }
)
#: The real endpoint's SysCommands: ``__<name>`` calls ``SysCommands.<name>(**params)``, so an
#: unknown command (AttributeError) or a missing or extra key (TypeError) ends its client
#: thread and closes the connection. Values: (required keys, optional keys).
_REAL_SYSCOMMANDS: dict[str, tuple[frozenset[str], frozenset[str]]] = {
    wire.SUBSCRIBE: (frozenset({"topic", "message_name"}), frozenset()),
    wire.PUBLISH: (frozenset({"topic", "message_name"}), frozenset({"queue_size", "latch"})),
    wire.ROS_SERVICE: (frozenset({"topic", "message_name"}), frozenset()),
    wire.UNITY_SERVICE: (frozenset({"topic", "message_name"}), frozenset()),
    wire.REQUEST: (frozenset({"srv_id"}), frozenset()),
    wire.RESPONSE: (frozenset({"srv_id"}), frozenset()),
    wire.TOPIC_LIST: (frozenset(), frozenset()),
}

log = logging.getLogger("uwval.bridge.server")


@functools.lru_cache(maxsize=256)
def _has_header(msg_name: str) -> bool:
    """Whether a ROS 1 message's first field is a std_msgs/Header (rospy's ``_has_header``);
    False for a type rosbags does not know."""
    from uwval.io.ros import normalize_type_name, typestore

    fields = typestore(1).fielddefs.get(normalize_type_name(msg_name))
    return bool(fields and fields[1] and fields[1][0][1][1:] == ("std_msgs/msg/Header",))


#: Selector keys' data for the listening socket and the wake-up socket.
_LISTENER = object()
_WAKE = object()

#: Callback for messages Unity publishes: (topic, body bytes, client id).
TopicCallback = Callable[[str, bytes, int], None]
#: ROS service handler: request body -> response body.
ServiceHandler = Callable[[bytes], bytes]


@dataclass
class ClientStats:
    """Counters of one connection (frames and bytes each way, drops, why it closed)."""

    client_id: int
    address: str
    frames_in: int = 0
    frames_out: int = 0
    bytes_in: int = 0
    bytes_out: int = 0
    dropped: int = 0
    subscriptions: tuple[str, ...] = ()
    closed_reason: str = ""


@dataclass
class _Client:
    sock: socket.socket
    client_id: int
    address: str
    max_queue: int
    max_frame: int
    server: BridgeServer
    queue: deque[bytes] = field(default_factory=deque)
    lock: threading.Lock = field(default_factory=threading.Lock)  # queue, partial, sends
    closed: bool = False
    stats: ClientStats | None = None
    subscriptions: dict[str, str] = field(default_factory=dict)  # topic -> message name
    publications: dict[str, str] = field(default_factory=dict)
    unity_services: dict[str, str] = field(default_factory=dict)
    ros_services: dict[str, str] = field(default_factory=dict)
    pending_srv: tuple[int, bool] | None = None  # (srv_id, is_request) for the next frame
    partial: memoryview | None = None  # unsent tail of data already partly on the wire
    partial_frames: int = 0  # frames that are complete once ``partial`` is sent
    writing: bool = False  # registered for write readiness (or asked to be)
    connected_at: float = 0.0  # time.monotonic()
    last_heard: float = 0.0  # time.monotonic() of the last bytes received
    last_active: float = 0.0  # time.monotonic() of the last frame other than a keepalive
    parser: wire.FrameParser | None = None

    @property
    def registered(self) -> bool:
        """Whether the client registered anything (a topic, a publisher, a service)."""
        return bool(
            self.subscriptions or self.publications or self.unity_services or self.ros_services
        )

    def enqueue(self, item: bytes) -> bool:
        """Send or queue one atomic item; False if the client is closed.

        Fast path: when nothing is queued and nothing is partly sent, the caller sends the
        item itself with a non-blocking send; whatever the socket does not take is finished by
        the I/O thread first. Otherwise the item is queued; a full queue drops its oldest item
        (never the frame partly on the wire).
        """
        with self.lock:
            if self.closed:
                return False
            assert self.stats is not None
            if not self.queue and self.partial is None:
                try:
                    sent = self.sock.send(item)
                except OSError:  # would block, or broken: the I/O thread handles it
                    sent = 0
                self.stats.bytes_out += sent
                if sent == len(item):
                    self.stats.frames_out += 1
                    return True
                # Part of a frame may be on the wire: the rest goes next, never dropped.
                self.partial = memoryview(item)[sent:]
                self.partial_frames = 1
            else:
                if len(self.queue) >= self.max_queue:
                    self.queue.popleft()
                    self.stats.dropped += 1
                self.queue.append(item)
            if self.writing:
                return True
            self.writing = True
        self.server._want_write(self)
        return True

    def flush(self) -> str | None:
        """Send what the socket takes now (I/O thread). Returns a close reason or None."""
        assert self.stats is not None
        with self.lock:
            while True:
                if self.partial is not None:
                    data, frames = self.partial, self.partial_frames
                elif self.queue:
                    items: list[bytes] = []
                    size = 0
                    while self.queue and size < _WRITE_BATCH_BYTES:
                        item = self.queue.popleft()
                        items.append(item)
                        size += len(item)
                    data, frames = memoryview(b"".join(items)), len(items)
                else:
                    self.writing = False
                    return None
                try:
                    sent = self.sock.send(data)
                except BlockingIOError:
                    sent = 0
                except OSError as exc:
                    return f"send failed: {exc}"
                self.stats.bytes_out += sent
                if sent < len(data):
                    self.partial, self.partial_frames = data[sent:], frames
                    return None  # the socket is full: wait for write readiness
                self.partial, self.partial_frames = None, 0
                self.stats.frames_out += frames


#: Bytes of queued frames joined into one send by the I/O thread.
_WRITE_BATCH_BYTES = 256 * 1024
#: Bytes read from a socket per readiness event (one read per event keeps clients fair).
_READ_BYTES = 256 * 1024
#: Seconds between checks of the idle and unused timeouts.
_SWEEP_S = 0.25


def _short(text: str, limit: int) -> str:
    """``text`` cut to ``limit`` characters, saying how long it was."""
    return text if len(text) <= limit else f"{text[:limit]}... ({len(text)} characters)"


#: SO_LINGER (on, 0 s): close with a reset, leaving no TIME_WAIT for a refused connection.
_LINGER_RESET = struct.pack("ii", 1, 0)


class BridgeServer:
    """ROS-TCP-Endpoint-compatible server (default 127.0.0.1:10000).

    Args:
        host, port: where to listen (``port=0`` picks a free port; see :attr:`address`).
        protocol: ``"ROS2"`` (CDR bodies) or ``"ROS1"``, announced in the handshake;
            default ROS2, or ROS1 with ``compat="real-endpoint"`` (the 0.7.0 ROS 1 release).
        queue_size: bound of each client's outgoing queue (items).
        max_frame: cap on one incoming frame's payload, bytes.
        max_clients: bound on simultaneous connections (see the module's eviction rule).
        unused_timeout: seconds a connection may stay without sending any frame (a keepalive
            counts) or registering anything before it is closed; ``None`` keeps it.
        idle_timeout: seconds any connection may stay silent (no frame, no keepalive) before
            it is closed (default 5 s: five missed keepalives); ``None`` keeps it.
        evict_silent: seconds of silence after which an unused connection gives its slot to
            a new one when all ``max_clients`` slots are taken.
        compat: ``"uwval"`` (default) or ``"real-endpoint"``: behave as ROS-TCP-Endpoint
            0.7.0 does where it is stricter, so that a Unity app tested here does not break
            on the real one: an unknown system command, a client-sent ``__handshake`` or
            ``__remove_subscriber``, or a missing or extra JSON key closes the connection; a
            message class outside the known packages gets ``__error`` and is not
            registered; registrations belong to the endpoint, not the connection (kept
            across reconnects, and a client's publications come back to it when it also
            subscribes); ``__topic_list`` answers the published topics of the ROS graph;
            with ROS1, a message with a header that a client publishes reaches the ROS side
            with ``header.seq`` rewritten (rospy's publisher counts 1, 2, ... per topic);
            the handshake announces ROS1 unless ``protocol`` says otherwise.
        route: one of :data:`ROUTES`; default: ``newest`` with ``compat="real-endpoint"``
            (the real endpoint sends everything to its newest connection), ``subscribers``
            otherwise.
        known_packages: message packages resolvable besides ``STANDARD_MSG_PACKAGES``
            (``compat="real-endpoint"`` only).
    """

    def __init__(
        self,
        host: str = wire.DEFAULT_HOST,
        port: int = wire.DEFAULT_PORT,
        *,
        protocol: wire.Protocol | None = None,
        queue_size: int = 1024,
        max_frame: int = wire.MAX_FRAME_BYTES,
        max_clients: int = DEFAULT_MAX_CLIENTS,
        unused_timeout: float | None = DEFAULT_UNUSED_TIMEOUT_S,
        idle_timeout: float | None = DEFAULT_IDLE_TIMEOUT_S,
        evict_silent: float = EVICT_SILENT_S,
        compat: str = "uwval",
        known_packages: frozenset[str] | set[str] = frozenset(),
        route: str | None = None,
    ) -> None:
        self.host = host
        self.port = port
        if compat not in COMPAT_MODES:
            raise BridgeError(f"compat must be one of {', '.join(COMPAT_MODES)}, got {compat!r}")
        real = compat == "real-endpoint"
        self.protocol = wire.check_protocol(protocol or ("ROS1" if real else "ROS2"))
        self.route = route or ("newest" if real else "subscribers")
        if self.route not in ROUTES or (self.route == "newest" and not real):
            raise BridgeError(
                f"route must be one of {', '.join(ROUTES)} (newest only with compat "
                f"real-endpoint), got {route!r}"
            )
        self.queue_size = int(queue_size)
        self.max_frame = int(max_frame)
        if self.queue_size < 1:
            raise BridgeError(f"queue size must be >= 1 item, got {queue_size}")
        if self.max_frame < 1:
            raise BridgeError(f"max frame size must be >= 1 byte, got {max_frame}")
        self.max_clients = int(max_clients)
        if self.max_clients < 1:
            raise BridgeError(f"max clients must be >= 1, got {max_clients}")
        for what, value in (("unused timeout", unused_timeout), ("idle timeout", idle_timeout)):
            if value is not None and not (0 < value < 1e9):  # NaN fails too
                raise BridgeError(f"{what} must be a positive number of seconds, got {value}")
        if not evict_silent >= 0:
            raise BridgeError(f"evict_silent must be >= 0 s, got {evict_silent}")
        self.compat = compat
        #: ``route="newest"``: the connection everything goes to (None after it closed,
        #: until the next one connects, as the real endpoint's sender queue).
        self._newest: _Client | None = None
        #: real-endpoint mode, ROS1: rospy's per-topic publish count (header.seq).
        self._pub_seq: dict[str, int] = {}
        self.known_packages = STANDARD_MSG_PACKAGES | frozenset(known_packages)
        # real-endpoint mode: registrations of the endpoint (topic -> message name)
        self._endpoint_subs: dict[str, str] = {}
        self._endpoint_pubs: dict[str, str] = {}
        self.unused_timeout = unused_timeout
        self.evict_silent = float(evict_silent)
        self.idle_timeout = idle_timeout
        #: Connections closed on arrival because ``max_clients`` were connected.
        self.refused = 0
        #: Unused connections closed to make room for a new one.
        self.evicted = 0
        #: Connections closed since the start (their stats: :meth:`closed_clients`).
        self.closed_count = 0
        self._listener: socket.socket | None = None
        self._selector: selectors.BaseSelector | None = None
        self._io_thread: threading.Thread | None = None
        self._wake_r: socket.socket | None = None
        self._wake_w: socket.socket | None = None
        self._requests: deque[tuple[str, _Client, str]] = deque()  # from other threads
        self._stopping = threading.Event()
        self._lock = threading.RLock()
        self._clients: dict[int, _Client] = {}
        self._closed_stats: deque[ClientStats] = deque(maxlen=CLOSED_STATS_KEPT)
        self._ids = itertools.count(1)
        self._srv_ids = itertools.count(1001)
        self._advertised: dict[str, str] = {}  # ROS-side topics -> pkg/Type
        self._callbacks: dict[str, list[TopicCallback]] = {}
        self._services: dict[str, ServiceHandler] = {}
        self._waiting: dict[int, tuple[threading.Event, list[bytes]]] = {}
        self._sub_cond = threading.Condition(self._lock)
        self._accept_paused_until = 0.0
        self._last_trim = 0.0
        self._log_window_start, self._log_count, self._log_suppressed = time.monotonic(), 0, 0
        self._read_buffer = bytearray(_READ_BYTES)  # the I/O thread's only read buffer
        self._read_view = memoryview(self._read_buffer)
        #: Human-readable events (connects, registrations, closes with reasons), newest last.
        self.events: deque[str] = deque(maxlen=EVENTS_KEPT)

    # ------------------------------------------------------------------ lifecycle
    def start(self) -> BridgeServer:
        """Bind, listen and start serving clients on one background I/O thread."""
        if not 0 <= self.port <= 65535:
            raise BridgeError(f"port must be 0-65535, got {self.port}")
        sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            sock.bind((self.host, self.port))
        except (OSError, OverflowError) as exc:
            sock.close()
            raise BridgeError(f"cannot listen on {self.host}:{self.port}: {exc}") from exc
        sock.listen(socket.SOMAXCONN)
        sock.setblocking(False)
        self._listener = sock
        self.port = sock.getsockname()[1]
        self._wake_r, self._wake_w = socket.socketpair()
        self._wake_r.setblocking(False)
        self._wake_w.setblocking(False)
        self._selector = selectors.DefaultSelector()
        self._selector.register(sock, selectors.EVENT_READ, _LISTENER)
        self._selector.register(self._wake_r, selectors.EVENT_READ, _WAKE)
        self._io_thread = threading.Thread(
            target=self._io_loop, daemon=True, name=f"bridge-io-{self.port}"
        )
        self._io_thread.start()
        self._event(f"listening on {self.host}:{self.port} ({self.protocol})")
        return self

    @property
    def address(self) -> tuple[str, int]:
        """(host, port) actually bound."""
        return self.host, self.port

    def stop(self) -> None:
        """Stop accepting, close every client and join the I/O thread."""
        self._stopping.set()
        if self._io_thread is not None:
            self._wake()
            if self._io_thread is not threading.current_thread():
                self._io_thread.join(timeout=5)
        with self._lock:
            clients = list(self._clients.values())
        for c in clients:  # only if the I/O thread did not get to them
            self._finish_close(c, "server stopping")
        for s in (self._listener, self._wake_r, self._wake_w):
            if s is not None:
                s.close()
        if self._selector is not None:
            with contextlib.suppress(Exception):
                self._selector.close()

    def __enter__(self) -> BridgeServer:
        return self.start() if self._listener is None else self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    # ------------------------------------------------------------------ ROS side API
    def advertise(self, topic: str, msg_name: str) -> None:
        """Declare a ROS-side topic (listed in ``__topic_list`` replies)."""
        with self._lock:
            self._advertised[topic] = wire.message_name(msg_name)

    def publish(self, topic: str, body: bytes) -> int:
        """Send one message body on ``topic`` to every client subscribed to it.

        The frame is encoded once and queued per client. Returns the number of clients
        it was queued to (0 when nobody subscribes, as a ROS publisher with no peers).
        """
        with self._lock:
            if topic in self._endpoint_subs:  # real-endpoint mode: the endpoint subscribed
                targets = self._endpoint_targets()
            else:
                targets = [c for c in self._clients.values() if topic in c.subscriptions]
        if not targets:
            return 0
        frame = wire.encode_frame(topic, body)
        return sum(c.enqueue(frame) for c in targets)

    def on_topic(self, topic: str, callback: TopicCallback) -> None:
        """Call ``callback(topic, body, client_id)`` for each message Unity publishes there."""
        with self._lock:
            self._callbacks.setdefault(topic, []).append(callback)

    def add_service(self, name: str, handler: ServiceHandler) -> None:
        """Serve a ROS service that Unity calls (after it sent ``__ros_service``)."""
        with self._lock:
            self._services[name] = handler

    def call_unity_service(self, name: str, request: bytes, timeout: float = 5.0) -> bytes:
        """Call a service that a Unity client registered with ``__unity_service``."""
        with self._lock:
            client = next((c for c in self._clients.values() if name in c.unity_services), None)
            if client is None:
                raise BridgeError(f"no connected client offers Unity service {name!r}")
            srv_id = next(self._srv_ids)
            done = threading.Event()
            box: list[bytes] = []
            self._waiting[srv_id] = (done, box)
        client.enqueue(
            wire.encode_command(wire.REQUEST, {"srv_id": srv_id}, nul=False)
            + wire.encode_frame(name, request, nul=False)
        )
        if not done.wait(timeout):
            with self._lock:
                self._waiting.pop(srv_id, None)
            raise BridgeError(
                f"Unity service {name!r} (srv_id {srv_id}) timed out after {timeout} s"
            )
        return box[0]

    def send_log(self, level: str, text: str) -> None:
        """Send ``__log`` / ``__warn`` / ``__error`` text to every client."""
        cmd = {"info": wire.LOG, "log": wire.LOG, "warn": wire.WARN, "error": wire.ERROR}[level]
        with self._lock:
            clients = (
                ([self._newest] if self._newest else [])
                if self.route == "newest"
                else list(self._clients.values())
            )
        for c in clients:  # in each peer's own NUL convention, as every other reply
            c.enqueue(wire.encode_command(cmd, {"text": text}, nul=False))

    def wait_for_subscribers(self, topic: str, count: int = 1, timeout: float = 5.0) -> None:
        """Block until ``count`` connected clients subscribe to ``topic``."""
        self.wait_for_registration(topic, "subscribe", count, timeout)

    def wait_for_registration(
        self, topic: str, kind: str = "subscribe", count: int = 1, timeout: float = 5.0
    ) -> None:
        """Block until ``count`` clients registered ``topic`` as ``kind`` (``subscribe``,
        ``publish``, ``ros_service`` or ``unity_service``)."""
        deadline = time.monotonic() + timeout
        with self._sub_cond:
            while self.registration_count(topic, kind) < count:
                left = deadline - time.monotonic()
                if left <= 0:
                    raise BridgeError(
                        f"timed out after {timeout} s waiting for {count} "
                        f"{kind} registration(s) of {topic!r}"
                    )
                self._sub_cond.wait(left)

    def subscriber_count(self, topic: str) -> int:
        """How many connected clients subscribe to ``topic``."""
        return self.registration_count(topic, "subscribe")

    def registration_count(self, topic: str, kind: str = "subscribe") -> int:
        """How many connected clients registered ``topic`` as ``kind``."""
        attr = {
            "subscribe": "subscriptions",
            "publish": "publications",
            "ros_service": "ros_services",
            "unity_service": "unity_services",
        }[kind]
        with self._lock:
            return sum(topic in getattr(c, attr) for c in self._clients.values())

    def disconnect(self, client_id: int, reason: str = "closed by the server") -> bool:
        """Close one client's connection (fault injection, admin). False if unknown."""
        with self._lock:
            client = self._clients.get(client_id)
        if client is None:
            return False
        self._close(client, reason)
        deadline = time.monotonic() + 2.0
        while not client.closed and time.monotonic() < deadline:  # the I/O thread closes it
            time.sleep(0.001)
        return True

    def clients(self) -> list[ClientStats]:
        """Stats of connected clients."""
        with self._lock:
            out = []
            for c in self._clients.values():
                assert c.stats is not None
                c.stats.subscriptions = tuple(sorted(c.subscriptions))
                out.append(c.stats)
            return out

    def closed_clients(self) -> list[ClientStats]:
        """Stats of the last ``CLOSED_STATS_KEPT`` clients that disconnected, with the reason
        (:attr:`closed_count` counts them all)."""
        with self._lock:
            return list(self._closed_stats)

    # ------------------------------------------------------------------ internals
    def _event(self, text: str, level: int = logging.INFO) -> None:
        text = _short(text, EVENT_TEXT_CHARS)
        self.events.append(text)
        # a flood of hostile clients must not flood the log (nor grow its formatter's caches)
        now = time.monotonic()
        if now - self._log_window_start >= LOG_WINDOW_S:
            if self._log_suppressed:
                log.warning(
                    "%d more server messages in the last %.0f s not logged (at most %d per window)",
                    self._log_suppressed,
                    now - self._log_window_start,
                    LOG_BURST,
                )
            self._log_window_start, self._log_count, self._log_suppressed = now, 0, 0
        if self._log_count < LOG_BURST:
            self._log_count += 1
            log.log(level, text)
        else:
            self._log_suppressed += 1

    def _on_io_thread(self) -> bool:
        return self._io_thread is threading.current_thread()

    def _wake(self) -> None:
        """Wake the I/O thread's select() (from another thread)."""
        if self._wake_w is not None:
            with contextlib.suppress(OSError):  # full: a wake-up is pending anyway
                self._wake_w.send(b"\0")

    def _want_write(self, c: _Client) -> None:
        """Ask for write readiness of ``c`` (its queue or a partial frame waits)."""
        if self._on_io_thread():
            self._watch(c, write=True)
        else:
            self._requests.append(("write", c, ""))
            self._wake()

    def _watch(self, c: _Client, write: bool) -> None:
        assert self._selector is not None
        if c.closed:
            return
        events = selectors.EVENT_READ | (selectors.EVENT_WRITE if write else 0)
        with contextlib.suppress(KeyError, ValueError, OSError):
            self._selector.modify(c.sock, events, c)

    def _io_loop(self) -> None:
        """Serve the listener and every client until stopped; no failure ends it."""
        sel = self._selector
        assert sel is not None
        next_sweep = time.monotonic() + _SWEEP_S
        while not self._stopping.is_set():
            try:
                ready = sel.select(timeout=_SWEEP_S)
            except (OSError, ValueError) as exc:  # a descriptor closed under us
                self._event(f"select failed: {exc}", logging.WARNING)
                time.sleep(ACCEPT_BACKOFF_S)
                continue
            for key, mask in ready:
                try:
                    self._ready(key, mask)
                except Exception as exc:  # a bug must not kill the server
                    if isinstance(key.data, _Client):
                        self._close(key.data, f"internal error: {type(exc).__name__}: {exc}")
                    else:
                        self._event(f"I/O loop: {type(exc).__name__}: {exc}", logging.ERROR)
            while self._requests:
                what, c, reason = self._requests.popleft()
                if what == "close":
                    self._close(c, reason)
                elif not c.closed:
                    self._watch(c, write=True)
            now = time.monotonic()
            if now >= next_sweep:
                next_sweep = now + _SWEEP_S
                self._sweep(now)
        with self._lock:
            clients = list(self._clients.values())
        for c in clients:
            self._close(c, "server stopping")

    def _ready(self, key: selectors.SelectorKey, mask: int) -> None:
        if key.data is _WAKE:
            with contextlib.suppress(OSError):
                while self._wake_r is not None and self._wake_r.recv(4096):
                    pass
        elif key.data is _LISTENER:
            self._accept_some()
        else:
            c: _Client = key.data
            if mask & selectors.EVENT_READ and not c.closed:
                self._read(c)
            if mask & selectors.EVENT_WRITE and not c.closed:
                reason = c.flush()
                if reason is not None:
                    self._close(c, reason)
                elif not c.writing:
                    self._watch(c, write=False)

    def _sweep(self, now: float) -> None:
        """Close connections past their unused or idle timeout; resume a paused accept."""
        if self._accept_paused_until and now >= self._accept_paused_until:
            self._accept_paused_until = 0.0
            assert self._selector is not None and self._listener is not None
            with contextlib.suppress(KeyError, ValueError, OSError):
                self._selector.register(self._listener, selectors.EVENT_READ, _LISTENER)
        with self._lock:
            clients = list(self._clients.values())
        for c in clients:
            if self.idle_timeout is not None and now - c.last_heard > self.idle_timeout:
                self._close(
                    c,
                    f"idle for {now - c.last_heard:.1f} s (no frame or keepalive within the "
                    f"idle timeout of {self.idle_timeout:g} s)",
                )
            elif (
                self.unused_timeout is not None
                and not c.registered
                and c.stats is not None
                and c.stats.frames_in == 0
                and now - c.connected_at > self.unused_timeout
            ):
                self._close(
                    c,
                    f"sent nothing and registered nothing within {self.unused_timeout:g} s of "
                    "connecting (the unused-connection timeout)",
                )

    def _accept_some(self) -> None:
        """Accept the connections waiting (a bounded number per wake-up, for fairness)."""
        listener = self._listener
        assert listener is not None and self._selector is not None
        for _ in range(64):
            try:
                conn, addr = listener.accept()
            except BlockingIOError:
                return
            except OSError as exc:
                if self._stopping.is_set() or listener.fileno() < 0:
                    return
                # out of descriptors, a connection reset before accept...: keep serving the
                # connected clients, and try again a little later
                self._event(f"accept failed: {exc}", logging.WARNING)
                with contextlib.suppress(KeyError, ValueError):
                    self._selector.unregister(listener)
                self._accept_paused_until = time.monotonic() + ACCEPT_BACKOFF_S
                return
            try:
                self._admit(conn, addr)
            except Exception as exc:  # never let one connection end the loop
                self._event(f"could not serve {addr}: {type(exc).__name__}: {exc}", logging.ERROR)
                with contextlib.suppress(OSError):
                    conn.close()

    def _evictable(self, now: float) -> _Client | None:
        """The connection that gives its slot to a new one when all are taken: the
        longest-silent one that never registered anything, if silent ``evict_silent``; else
        the one that has sent nothing but keepalives (or nothing) for longest, if for
        ``evict_silent``: a flood of connections that register and then only idle cannot keep
        a new client out (a real Unity that loses its slot reconnects after 1 s)."""
        with self._lock:
            live = [c for c in self._clients.values() if not c.closed]
        unused = [c for c in live if not c.registered]
        if unused:
            oldest = min(unused, key=lambda c: c.last_heard)
            if now - oldest.last_heard >= self.evict_silent:
                return oldest
        if not live:
            return None
        idlest = min(live, key=lambda c: c.last_active)
        return idlest if now - idlest.last_active >= self.evict_silent else None

    def _admit(self, conn: socket.socket, addr: Any) -> None:
        """Start serving one accepted connection, or close it if ``max_clients`` are served."""
        now = time.monotonic()
        with self._lock:
            full = len(self._clients) >= self.max_clients
        if full:
            victim = self._evictable(now)
            if victim is not None:
                self.evicted += 1
                what = (
                    f"registered nothing and was silent for {now - victim.last_heard:.1f} s"
                    if not victim.registered
                    else f"sent nothing but keepalives for {now - victim.last_active:.1f} s"
                )
                self._close(
                    victim,
                    f"evicted: {self.max_clients} clients connected (the limit) and this one "
                    f"{what}",
                )
                full = False
        if full:
            self.refused += 1
            with contextlib.suppress(OSError):
                conn.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, _LINGER_RESET)
            conn.close()
            if self.refused == 1 or self.refused % 1000 == 0:
                self._event(
                    f"refused a connection from {addr[0]}:{addr[1]}: {self.max_clients} "
                    f"clients connected (the limit); {self.refused} refused so far",
                    logging.WARNING,
                )
            return
        conn.setblocking(False)
        conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        cid = next(self._ids)
        address = f"{addr[0]}:{addr[1]}"
        client = _Client(conn, cid, address, self.queue_size, self.max_frame, self)
        client.stats = ClientStats(cid, address)
        client.connected_at = client.last_heard = client.last_active = now
        client.parser = wire.FrameParser(max_frame=self.max_frame)
        assert self._selector is not None
        self._selector.register(conn, selectors.EVENT_READ, client)
        # The endpoint's first frame is the handshake (version + protocol): queued before the
        # client is visible to publish()/send_log() on other threads, so nothing overtakes it.
        client.enqueue(wire.handshake_frame(self.protocol))
        with self._lock:
            self._clients[cid] = client
            self._newest = client
        self._event(f"client {cid} connected from {address}")

    def _read(self, c: _Client) -> None:
        """Read what one readable client sent and dispatch its complete frames."""
        assert c.stats is not None and c.parser is not None
        try:
            # into one reused buffer: a fresh 256 KiB bytes per read, shrunk to what came,
            # fragments the heap (RSS that never comes back)
            n = c.sock.recv_into(self._read_buffer)
        except BlockingIOError:
            return
        except OSError as exc:
            self._close(c, f"receive failed: {exc}")
            return
        parser = c.parser
        data = self._read_view[:n]
        if not n:
            reason = "peer closed the connection"
            if parser.buffered:
                reason = (
                    f"peer closed mid-frame: {parser.buffered} bytes of an "
                    f"incomplete frame at byte {parser.offset}"
                )
            self._close(c, reason)
            return
        c.last_heard = time.monotonic()
        c.stats.bytes_in += n
        try:
            for frame in parser.feed(data):
                c.stats.frames_in += 1
                if not frame.is_keepalive:
                    c.last_active = c.last_heard
                self._dispatch(c, frame)
                if c.closed:
                    return
        except wire.ProtocolError as exc:
            reason = f"protocol error: {exc}"
            self._event(f"client {c.client_id} ({c.address}): {reason}", logging.WARNING)
            self._close(c, reason)

    def _close(self, c: _Client, reason: str) -> None:
        """Close one client (any thread; off the I/O thread it is handed over)."""
        if self._io_thread is not None and self._io_thread.is_alive() and not self._on_io_thread():
            with c.lock:
                if c.closed:
                    return
            self._requests.append(("close", c, reason))
            self._wake()
            return
        self._finish_close(c, reason)

    def _finish_close(self, c: _Client, reason: str) -> None:
        with c.lock:
            if c.closed:
                return
            c.closed = True
            c.queue.clear()
            c.partial = None
        # Bookkeeping first, so whoever sees the socket close also sees the reason.
        with self._lock:
            self._clients.pop(c.client_id, None)
            if self._newest is c:
                self._newest = None
            assert c.stats is not None
            c.stats.closed_reason = reason
            # a closed client's names are kept short: 256 kept stats of 16 names of 1 KiB
            # would hold 4 MiB after the clients left
            c.stats.subscriptions = tuple(
                _short(t, CLOSED_NAME_CHARS) for t in sorted(c.subscriptions)[:16]
            )
            self._closed_stats.append(c.stats)
            self.closed_count += 1
            self._sub_cond.notify_all()
            idle = not self._clients
        if self._selector is not None:
            with contextlib.suppress(KeyError, ValueError, OSError):
                self._selector.unregister(c.sock)
        with contextlib.suppress(OSError):
            c.sock.shutdown(socket.SHUT_RDWR)
        c.sock.close()
        c.parser = None
        self._event(f"client {c.client_id} ({c.address}) closed: {reason}")
        now = time.monotonic()
        if idle and now - self._last_trim >= 1.0:  # at most once a second (a flood comes and
            # goes): the last client left: free what only the cyclic GC frees (an exception
            # with its frames)
            self._last_trim = now
            gc.collect()

    def _reply(self, c: _Client, command: str, params: dict[str, Any]) -> None:
        to = self._route_to(c)
        if to is not None:
            to.enqueue(wire.encode_command(command, params, nul=False))

    def _route_to(self, c: _Client) -> _Client | None:
        """Who gets a reply to ``c``: ``c``, or with ``route="newest"`` the newest connection
        (None when it has closed)."""
        if self.route != "newest":
            return c
        with self._lock:
            return self._newest

    def _endpoint_targets(self) -> list[_Client]:
        """Clients a message of the endpoint's own subscriptions goes to (lock held)."""
        if self.route == "newest":
            return [self._newest] if self._newest is not None else []
        return list(self._clients.values())

    def _dispatch(self, c: _Client, frame: wire.Frame) -> None:
        if c.pending_srv is not None:
            srv_id, is_request = c.pending_srv
            c.pending_srv = None
            if is_request:
                self._serve_request(c, srv_id, frame)
            else:
                with self._lock:
                    waiting = self._waiting.pop(srv_id, None)
                if waiting is None:
                    self._reply(c, wire.ERROR, {"text": f"unexpected __response srv_id {srv_id}"})
                else:
                    waiting[1].append(frame.payload)
                    waiting[0].set()
            return
        if frame.is_keepalive:
            return
        if frame.is_command:
            self._command(c, frame)
            return
        topic = frame.destination
        if self.compat == "real-endpoint":
            self._dispatch_real(c, topic, frame.payload)
            return
        if topic not in c.publications:
            self._reply(
                c,
                wire.ERROR,
                {
                    "text": f"Not registered to publish topic '{topic}'! "
                    f"Valid publish topics are: "
                    f"{sorted(c.publications)}"
                },
            )
            return
        with self._lock:
            callbacks = list(self._callbacks.get(topic, ()))
            others = [o for o in self._clients.values() if o is not c and topic in o.subscriptions]
        for cb in callbacks:
            cb(topic, frame.payload, c.client_id)
        if others:
            data = wire.encode_frame(topic, frame.payload)
            for o in others:
                o.enqueue(data)

    def _dispatch_real(self, c: _Client, topic: str, payload: bytes) -> None:
        """A client's message as ROS-TCP-Endpoint handles it: published into ROS by the
        endpoint's publisher, so the endpoint's own subscriber (if any) sends it back."""
        with self._lock:
            registered = topic in self._endpoint_pubs
            pubs = list(self._endpoint_pubs)
            callbacks = list(self._callbacks.get(topic, ()))
            echo = topic in self._endpoint_subs
            targets = self._endpoint_targets() if echo else []
            if registered and self.protocol == "ROS1":
                payload = self._rospy_seq(topic, self._endpoint_pubs[topic], payload)
        if not registered:
            self._reply(
                c,
                wire.ERROR,
                {
                    "text": f"Not registered to publish topic '{topic}'! Valid publish topics "
                    f"are: dict_keys({pubs!r}) "
                },
            )
            return
        for cb in callbacks:
            cb(topic, payload, c.client_id)
        if targets:
            data = wire.encode_frame(topic, payload)
            for o in targets:
                o.enqueue(data)

    def _command_real(self, c: _Client, cmd: str, params: Any) -> bool:
        """Checks of the real endpoint's ``SysCommands`` dispatch. Returns False when the
        command was handled here (the connection closed, or an ``__error`` sent)."""
        spec = _REAL_SYSCOMMANDS.get(cmd)
        if spec is None:
            self._close(
                c,
                f"real-endpoint compat: {cmd} is not a command of ROS-TCP-Endpoint 0.7.0, "
                "which closes the connection here (AttributeError in its client thread)",
            )
            return False
        required, optional = spec
        keys = set(params) if isinstance(params, dict) else set()
        missing, extra = sorted(required - keys), sorted(keys - required - optional)
        if not isinstance(params, dict) or missing or extra:
            what = (
                "parameters are not a JSON object"
                if not isinstance(params, dict)
                else "; ".join(
                    x
                    for x in (
                        f"missing key(s) {', '.join(missing)}" if missing else "",
                        f"unexpected key(s) {', '.join(extra)}" if extra else "",
                    )
                    if x
                )
            )
            self._close(
                c,
                f"real-endpoint compat: {cmd}: {what}; ROS-TCP-Endpoint 0.7.0 closes the "
                "connection here (TypeError in its client thread)",
            )
            return False
        if cmd in (wire.SUBSCRIBE, wire.PUBLISH, wire.ROS_SERVICE, wire.UNITY_SERVICE):
            topic, name = str(params["topic"]), str(params["message_name"])
            with self._lock:
                held = len(self._endpoint_subs) + len(self._endpoint_pubs)
                new = topic not in self._endpoint_subs and topic not in self._endpoint_pubs
            if new and held >= MAX_ENDPOINT_REGISTRATIONS:
                # the endpoint's registrations outlive connections: bounded on their own
                self._reply(
                    c,
                    wire.ERROR,
                    {
                        "text": f"{cmd}({topic}): the endpoint holds {held} registrations "
                        "(the limit)"
                    },
                )
                return False
            pkg, _, cls = name.partition("/")
            with self._lock:
                advertised = name in self._advertised.values()
            if topic and not advertised and not (pkg in self.known_packages and cls.isidentifier()):
                text = {
                    wire.SUBSCRIBE: f"SysCommand.subscribe - Unknown message class '{name}'",
                    wire.PUBLISH: f"SysCommand.publish - Unknown message class '{name}'",
                    wire.ROS_SERVICE: (
                        f"RegisterRosService({topic}, {name}) - Unknown service class '{name}'"
                    ),
                    wire.UNITY_SERVICE: (
                        f"RegisterUnityService({topic}, {name}) - Unknown service class '{name}'"
                    ),
                }[cmd]
                self._reply(c, wire.ERROR, {"text": text})
                return False
        return True

    def _serve_request(self, c: _Client, srv_id: int, frame: wire.Frame) -> None:
        name = frame.destination
        with self._lock:
            handler = self._services.get(name)
        if handler is None:
            self._reply(
                c,
                wire.ERROR,
                {
                    "text": f"Service destination '{name}' is not "
                    f"registered! Known services are: "
                    f"{sorted(self._services)}"
                },
            )
            return
        try:
            response = handler(frame.payload)
        except Exception as exc:
            self._reply(c, wire.ERROR, {"text": f"service {name!r} failed: {exc}"})
            return
        to = self._route_to(c)
        if to is not None:
            to.enqueue(
                wire.encode_command(wire.RESPONSE, {"srv_id": srv_id}, nul=False)
                + wire.encode_frame(name, response, nul=False)
            )

    def _rospy_seq(self, topic: str, msg_name: str, payload: bytes) -> bytes:
        """A ROS 1 body as rospy's publisher sends it on: a message whose first field is a
        std_msgs/Header gets ``header.seq`` = the publisher's count (1, 2, ...; lock held)."""
        if len(payload) < 4 or not _has_header(msg_name):
            return payload
        seq = self._pub_seq.get(topic, 0) + 1
        self._pub_seq[topic] = seq
        return struct.pack("<I", seq & 0xFFFFFFFF) + payload[4:]

    def _command(self, c: _Client, frame: wire.Frame) -> None:
        cmd = frame.destination
        params = frame.json()
        where = f"client {c.client_id}: {cmd}"
        if self.compat == "real-endpoint" and not self._command_real(c, cmd, params):
            return
        if cmd in (wire.SUBSCRIBE, wire.PUBLISH, wire.ROS_SERVICE, wire.UNITY_SERVICE):
            topic = str(params.get("topic", ""))
            name = str(params.get("message_name", ""))
            if not topic:
                self._reply(c, wire.ERROR, {"text": f"{cmd}: can't register a blank topic name"})
                return
            too_long = [
                what
                for what, text in (("topic", topic), ("message name", name))
                if len(text.encode("utf-8", "surrogatepass")) > MAX_NAME_BYTES
            ]
            if too_long:
                self._reply(
                    c,
                    wire.ERROR,
                    {"text": f"{cmd}: {' and '.join(too_long)} longer than {MAX_NAME_BYTES} bytes"},
                )
                return
            if name.count("/") != 1 or not all(name.split("/")):
                # ROS-TCP-Endpoint cannot resolve such a class and does not register it.
                self._reply(
                    c,
                    wire.ERROR,
                    {
                        "text": f"{cmd}({topic}, {name}) - Unknown "
                        f"message class '{name}' (expected "
                        "pkg/Type)"
                    },
                )
                return
            table = {
                wire.SUBSCRIBE: c.subscriptions,
                wire.PUBLISH: c.publications,
                wire.ROS_SERVICE: c.ros_services,
                wire.UNITY_SERVICE: c.unity_services,
            }[cmd]
            held = (
                len(c.subscriptions)
                + len(c.publications)
                + len(c.ros_services)
                + len(c.unity_services)
            )
            if topic not in table and held >= MAX_REGISTRATIONS:
                self._reply(
                    c,
                    wire.ERROR,
                    {"text": f"{cmd}({topic}): more than {MAX_REGISTRATIONS} registrations"},
                )
                return
            with self._lock:
                table[topic] = name
                if self.compat == "real-endpoint":  # the endpoint's, kept across reconnects
                    if cmd == wire.SUBSCRIBE:
                        self._endpoint_subs[topic] = name
                    elif cmd == wire.PUBLISH:
                        self._endpoint_pubs[topic] = name
                self._sub_cond.notify_all()
            self._event(f"{where} {topic} ({name})")
        elif cmd in (wire.REQUEST, wire.RESPONSE):
            try:
                srv_id = int(params["srv_id"])
            except (KeyError, TypeError, ValueError, OverflowError):
                raise wire.ProtocolError(
                    f"{cmd} at byte {frame.offset} lacks an integer srv_id"
                ) from None
            c.pending_srv = (srv_id, cmd == wire.REQUEST)
        elif cmd == wire.TOPIC_LIST:
            with self._lock:
                topics = dict(self._advertised)
                if self.compat == "real-endpoint":
                    # rospy.get_published_topics(): the graph's published topics, among
                    # them the endpoint's own /rosout and its registered publishers
                    topics.setdefault("/rosout", "rosgraph_msgs/Log")
                    for t, n in self._endpoint_pubs.items():
                        topics.setdefault(t, n)
                for o in self._clients.values():
                    for t, n in o.publications.items():
                        topics.setdefault(t, n)
            names = sorted(topics)
            self._reply(c, wire.TOPIC_LIST, {"topics": names, "types": [topics[t] for t in names]})
        elif cmd in (wire.LOG, wire.WARN, wire.ERROR):
            level = {wire.LOG: logging.INFO, wire.WARN: logging.WARNING, wire.ERROR: logging.ERROR}[
                cmd
            ]
            self._event(f"{where}: {params.get('text', '')}", level)
        elif cmd == wire.HANDSHAKE:
            pass  # a client echoing a handshake is harmless
        else:
            self._reply(c, wire.ERROR, {"text": f"Don't understand SysCommand.'{cmd}'"})
