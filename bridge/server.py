"""The ROS-TCP endpoint: a TCP server that Unity (ROS-TCP-Connector v0.7) connects to.

It plays ROS-TCP-Endpoint's role. The "ROS side" is in-process: a Gazebo-side publisher
calls :meth:`BridgeServer.publish` as ros_gz_bridge's topics would reach the endpoint's
subscribers, and local callbacks receive what Unity publishes.

Robustness rules (issue 6):
- several clients at once, each with a reader thread and a writer thread;
- per-client bounded outgoing queue: when full the oldest item is dropped and counted
  (ROS-TCP-Endpoint's queues are unbounded, so overload there shows as growing lag);
- a frame-size cap; a malformed frame closes only that client, with a logged reason;
- a frame is queued atomically (a ``__response`` and its body travel as one item) so a drop
  never splits a pair.

Limits against hostile clients (issue 14), so that memory and threads stay bounded and the
accept loop never dies:
- at most ``max_clients`` connections (default 64, two threads each); one more is accepted
  and closed at once, without a thread, and counted in :attr:`BridgeServer.refused`;
- a system command's payload is at most ``protocol.MAX_COMMAND_BYTES`` (64 KiB), a frame's
  destination ``MAX_DESTINATION_BYTES`` (1 KiB); a registered topic or message name is at
  most ``MAX_NAME_BYTES`` (1 KiB, a longer topic could never be a frame's destination), and
  a client holds at most ``MAX_REGISTRATIONS`` (256) registrations;
- texts kept in :attr:`BridgeServer.events` are cut to ``EVENT_TEXT_CHARS``; the statistics
  of only the last ``CLOSED_STATS_KEPT`` closed clients are kept (their subscription lists
  cut to 16 names), so memory comes back when clients leave;
- the listen backlog is the system's ``SOMAXCONN`` (bursts of connections do not wait for
  SYN retries); an accept or thread-start failure (out of descriptors, "can't start new
  thread") closes that one connection, and the loop goes on.

Worst case per connection: the incoming frame buffer (``max_frame``, default 16 MiB, only
while a frame of that size is arriving), the outgoing queue (``queue_size`` frames) and
256 registrations of at most 2 KiB each.

Size: one module on purpose: one class (the endpoint) whose accept loop, per-client reader and
writer threads and limits share its locks and counters; splitting would expose that state.
"""

from __future__ import annotations

import contextlib
import itertools
import logging
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

#: Default bound on simultaneous connections (each has a reader and a writer thread).
DEFAULT_MAX_CLIENTS = 64
#: Registrations (subscribe, publish, services) one client may hold.
MAX_REGISTRATIONS = 256
#: Longest topic, service or message name accepted in a registration (bytes of UTF-8).
MAX_NAME_BYTES = wire.MAX_DESTINATION_BYTES
#: Longest text kept in an event (client log texts, names in messages).
EVENT_TEXT_CHARS = 300
#: Statistics of closed clients kept (the newest).
CLOSED_STATS_KEPT = 256
#: Seconds the accept loop pauses after an accept failure (e.g. out of file descriptors).
ACCEPT_BACKOFF_S = 0.05

log = logging.getLogger("uwval.bridge.server")

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
    queue: deque[bytes] = field(default_factory=deque)
    cond: threading.Condition = field(default_factory=threading.Condition)
    closed: bool = False
    stats: ClientStats | None = None
    subscriptions: dict[str, str] = field(default_factory=dict)  # topic -> message name
    publications: dict[str, str] = field(default_factory=dict)
    unity_services: dict[str, str] = field(default_factory=dict)
    ros_services: dict[str, str] = field(default_factory=dict)
    pending_srv: tuple[int, bool] | None = None  # (srv_id, is_request) for the next frame
    send_lock: threading.Lock = field(default_factory=threading.Lock)  # one writer at a time
    partial: bytes = b""  # unsent tail of a frame already partly on the wire
    partial_frames: int = 0
    threads: list[threading.Thread] = field(default_factory=list)

    def enqueue(self, item: bytes) -> bool:
        """Send or queue one atomic item; False if the client is closed.

        Fast path: when nothing is queued and no write is in progress, the caller sends
        the item itself with a non-blocking send (no thread hand-off, which is what keeps
        one-way latency low); whatever the socket does not take is finished by the writer
        thread first. Otherwise the item is queued; a full queue drops its oldest item.
        """
        with self.cond:
            if self.closed:
                return False
            assert self.stats is not None
            if (
                _DONTWAIT
                and not self.queue
                and not self.partial
                and self.send_lock.acquire(blocking=False)
            ):
                try:
                    try:
                        sent = self.sock.send(item, _DONTWAIT)
                    except OSError:  # would block, or broken: the writer thread handles it
                        sent = 0
                    if sent:
                        self.stats.bytes_out += sent
                        if sent == len(item):
                            self.stats.frames_out += 1
                            return True
                        # Part of a frame is on the wire: the rest goes next, never dropped.
                        self.partial = item[sent:]
                        self.partial_frames = 1
                        self.cond.notify()
                        return True
                finally:
                    self.send_lock.release()
            if len(self.queue) >= self.max_queue:
                self.queue.popleft()
                self.stats.dropped += 1
            self.queue.append(item)
            self.cond.notify()
        return True


#: Flag for a non-blocking send (Linux/macOS); 0 disables the direct-send fast path.
_DONTWAIT = getattr(socket, "MSG_DONTWAIT", 0)


def _load_malloc_trim() -> Callable[[int], int] | None:
    """glibc's ``malloc_trim`` (returns freed heap pages to the system), or None elsewhere."""
    try:
        import ctypes

        libc = ctypes.CDLL("libc.so.6")
        trim: Callable[[int], int] = libc.malloc_trim
    except (OSError, AttributeError):
        return None
    return trim


_MALLOC_TRIM = _load_malloc_trim()


#: SO_LINGER (on, 0 s): close with a reset, leaving no TIME_WAIT for a refused connection.
_LINGER_RESET = struct.pack("ii", 1, 0)


class BridgeServer:
    """ROS-TCP-Endpoint-compatible server (default 127.0.0.1:10000).

    Args:
        host, port: where to listen (``port=0`` picks a free port; see :attr:`address`).
        protocol: ``"ROS2"`` (CDR bodies) or ``"ROS1"``, announced in the handshake.
        queue_size: bound of each client's outgoing queue (items).
        max_frame: cap on one incoming frame's payload, bytes.
        max_clients: bound on simultaneous connections; more are closed on arrival.
    """

    def __init__(
        self,
        host: str = wire.DEFAULT_HOST,
        port: int = wire.DEFAULT_PORT,
        *,
        protocol: wire.Protocol = "ROS2",
        queue_size: int = 1024,
        max_frame: int = wire.MAX_FRAME_BYTES,
        max_clients: int = DEFAULT_MAX_CLIENTS,
    ) -> None:
        self.host = host
        self.port = port
        self.protocol = wire.check_protocol(protocol)
        self.queue_size = int(queue_size)
        self.max_frame = int(max_frame)
        if self.queue_size < 1:
            raise BridgeError(f"queue size must be >= 1 item, got {queue_size}")
        if self.max_frame < 1:
            raise BridgeError(f"max frame size must be >= 1 byte, got {max_frame}")
        self.max_clients = int(max_clients)
        if self.max_clients < 1:
            raise BridgeError(f"max clients must be >= 1, got {max_clients}")
        #: Connections closed on arrival because ``max_clients`` were connected.
        self.refused = 0
        #: Connections closed since the start (their stats: :meth:`closed_clients`).
        self.closed_count = 0
        self._listener: socket.socket | None = None
        self._accept_thread: threading.Thread | None = None
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
        #: Human-readable events (connects, registrations, closes with reasons), newest last.
        self.events: deque[str] = deque(maxlen=1000)

    # ------------------------------------------------------------------ lifecycle
    def start(self) -> BridgeServer:
        """Bind, listen and start accepting clients in a background thread."""
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
        sock.settimeout(0.1)
        self._listener = sock
        self.port = sock.getsockname()[1]
        self._accept_thread = threading.Thread(
            target=self._accept_loop, daemon=True, name=f"bridge-accept-{self.port}"
        )
        self._accept_thread.start()
        self._event(f"listening on {self.host}:{self.port} ({self.protocol})")
        return self

    @property
    def address(self) -> tuple[str, int]:
        """(host, port) actually bound."""
        return self.host, self.port

    def stop(self) -> None:
        """Stop accepting, close every client and join the threads."""
        self._stopping.set()
        if self._accept_thread is not None:
            # Wake accept() at once with a throwaway connection instead of waiting it out.
            with (
                contextlib.suppress(OSError),
                socket.create_connection(
                    (self.host if self.host not in ("", "0.0.0.0") else "127.0.0.1", self.port),
                    timeout=0.5,
                ),
            ):
                pass
            self._accept_thread.join(timeout=2)
        if self._listener is not None:
            self._listener.close()
        with self._lock:
            clients = list(self._clients.values())
        for c in clients:
            self._close(c, "server stopping")
        for c in clients:
            for t in c.threads:
                if t is not threading.current_thread():
                    t.join(timeout=2)

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
            clients = list(self._clients.values())
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
        if len(text) > EVENT_TEXT_CHARS:
            text = f"{text[:EVENT_TEXT_CHARS]}... ({len(text)} characters)"
        self.events.append(text)
        log.log(level, text)

    def _accept_loop(self) -> None:
        """Accept clients until stopped; no failure but a closed listener ends it."""
        listener = self._listener
        assert listener is not None
        while not self._stopping.is_set():
            try:
                conn, addr = listener.accept()
            except TimeoutError:
                continue
            except OSError as exc:
                if self._stopping.is_set() or listener.fileno() < 0:
                    break
                # out of descriptors, a connection reset before accept...: keep serving
                self._event(f"accept failed: {exc}", logging.WARNING)
                time.sleep(ACCEPT_BACKOFF_S)
                continue
            if self._stopping.is_set():
                conn.close()
                break
            try:
                self._admit(conn, addr)
            except Exception as exc:  # never let one connection end the accept loop
                self._event(f"could not serve {addr}: {type(exc).__name__}: {exc}", logging.ERROR)
                with contextlib.suppress(OSError):
                    conn.close()

    def _admit(self, conn: socket.socket, addr: Any) -> None:
        """Start serving one accepted connection, or close it if ``max_clients`` are served."""
        with self._lock:
            full = len(self._clients) >= self.max_clients
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
        conn.settimeout(None)
        conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        cid = next(self._ids)
        address = f"{addr[0]}:{addr[1]}"
        client = _Client(conn, cid, address, self.queue_size)
        client.stats = ClientStats(cid, address)
        # The endpoint's first frame is the handshake (version + protocol).
        client.queue.append(wire.handshake_frame(self.protocol))
        with self._lock:
            self._clients[cid] = client
        reader = threading.Thread(
            target=self._read_loop, args=(client,), daemon=True, name=f"bridge-read-{cid}"
        )
        writer = threading.Thread(
            target=self._write_loop, args=(client,), daemon=True, name=f"bridge-write-{cid}"
        )
        client.threads = [reader, writer]
        self._event(f"client {cid} connected from {address}")
        try:
            writer.start()
            reader.start()
        except RuntimeError as exc:  # "can't start new thread"
            self._close(client, f"cannot start its threads: {exc}")

    def _write_loop(self, c: _Client) -> None:
        assert c.stats is not None
        while True:
            with c.cond:
                while not c.queue and not c.partial and not c.closed:
                    c.cond.wait()
                if c.closed:
                    return
            # Hold send_lock while taking items so a direct send cannot overtake them.
            with c.send_lock:
                with c.cond:
                    items = ([c.partial] if c.partial else []) + list(c.queue)
                    n_frames = len(c.queue) + c.partial_frames
                    c.queue.clear()
                    c.partial, c.partial_frames = b"", 0
                if not items:
                    continue
                data = b"".join(items)
                try:
                    c.sock.sendall(data)
                except OSError as exc:
                    self._close(c, f"send failed: {exc}")
                    return
            c.stats.frames_out += n_frames
            c.stats.bytes_out += len(data)

    def _read_loop(self, c: _Client) -> None:
        assert c.stats is not None
        parser = wire.FrameParser(max_frame=self.max_frame)
        reason = "peer closed the connection"
        try:
            while not c.closed:
                try:
                    data = c.sock.recv(1 << 16)
                except OSError as exc:
                    reason = f"receive failed: {exc}"
                    break
                if not data:
                    if parser.buffered:
                        reason = (
                            f"peer closed mid-frame: {parser.buffered} bytes of an "
                            f"incomplete frame at byte {parser.offset}"
                        )
                    break
                c.stats.bytes_in += len(data)
                for frame in parser.feed(data):
                    c.stats.frames_in += 1
                    self._dispatch(c, frame)
        except wire.ProtocolError as exc:
            reason = f"protocol error: {exc}"
            self._event(f"client {c.client_id} ({c.address}): {reason}", logging.WARNING)
        except Exception as exc:  # a bug must not kill the server; close this client only
            reason = f"internal error: {type(exc).__name__}: {exc}"
            self._event(f"client {c.client_id} ({c.address}): {reason}", logging.ERROR)
        self._close(c, reason)

    def _close(self, c: _Client, reason: str) -> None:
        with c.cond:
            if c.closed:
                return
            c.closed = True
            c.cond.notify_all()
        # Bookkeeping first, so whoever sees the socket close also sees the reason.
        with self._lock:
            self._clients.pop(c.client_id, None)
            assert c.stats is not None
            c.stats.closed_reason = reason
            c.stats.subscriptions = tuple(sorted(c.subscriptions)[:16])
            self._closed_stats.append(c.stats)
            self.closed_count += 1
            self._sub_cond.notify_all()
            idle = not self._clients
        with contextlib.suppress(OSError):
            c.sock.shutdown(socket.SHUT_RDWR)
        c.sock.close()
        self._event(f"client {c.client_id} ({c.address}) closed: {reason}")
        if idle and _MALLOC_TRIM is not None:
            # the last client left: give the memory its buffers and threads used back to
            # the system (glibc keeps freed pages of per-thread arenas otherwise)
            _MALLOC_TRIM(0)

    def _reply(self, c: _Client, command: str, params: dict[str, Any]) -> None:
        c.enqueue(wire.encode_command(command, params, nul=False))

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
        c.enqueue(
            wire.encode_command(wire.RESPONSE, {"srv_id": srv_id}, nul=False)
            + wire.encode_frame(name, response, nul=False)
        )

    def _command(self, c: _Client, frame: wire.Frame) -> None:
        cmd = frame.destination
        params = frame.json()
        where = f"client {c.client_id}: {cmd}"
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
