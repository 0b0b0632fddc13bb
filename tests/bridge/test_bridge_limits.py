"""Issue 14: the bridge server under hostile clients keeps bounded connections, threads and
memory, refuses oversized system commands and names, and its accept loop never dies.
Loopback only, bounded loops (a measurement with 10,000 connections is
benchmarks/bridge_hostile.py)."""

from __future__ import annotations

import contextlib
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterator

import pytest
from raw_client import RawClient

from uwval.bridge import protocol as wire
from uwval.bridge.errors import BridgeError
from uwval.bridge.server import CLOSED_STATS_KEPT, MAX_REGISTRATIONS, BridgeServer


@pytest.fixture
def server() -> Iterator[BridgeServer]:
    with BridgeServer(port=0, max_clients=3) as s:
        yield s


def _wait(cond: object, what: str, seconds: float = 10.0) -> None:
    for _ in range(int(seconds * 100)):
        if cond():  # type: ignore[operator]
            return
        time.sleep(0.01)
    pytest.fail(f"timed out waiting for {what}")


def _server_threads() -> int:
    """Threads of bridge servers in this process (one I/O thread per server)."""
    return sum(t.name.startswith("bridge-") for t in threading.enumerate())


def _handshake(c: RawClient) -> None:
    dest, _ = c.read()
    assert dest == wire.HANDSHAKE


def _connect() -> socket.socket | None:
    """A connection to the server, or None if the server reset it at once (refused)."""
    try:
        return socket.create_connection(("127.0.0.1", PORT[0]), timeout=5)
    except ConnectionResetError:
        return None


PORT = [0]


def _closed_by_server(sock: socket.socket | None) -> bool:
    if sock is None:
        return True
    sock.settimeout(5)
    try:
        data = sock.recv(1 << 16)
        while data:  # a handshake may have been sent before the close
            data = sock.recv(1 << 16)
    except ConnectionResetError:
        return True
    return True


def test_connections_beyond_the_limit_are_closed_without_threads(server: BridgeServer) -> None:
    threads_before = _server_threads()
    used = [RawClient(server.port) for _ in range(3)]
    for i, c in enumerate(used):
        _handshake(c)
        c.command(wire.SUBSCRIBE, {"topic": f"/u{i}", "message_name": "std_msgs/String"})
        server.wait_for_subscribers(f"/u{i}")
    PORT[0] = server.port
    for _ in range(20):  # clients that use their connection are never evicted
        s = _connect()
        assert _closed_by_server(s)
        if s is not None:
            s.close()
    _wait(lambda: server.refused == 20, "20 refusals")
    assert len(server.clients()) == 3 and server.evicted == 0
    assert _server_threads() == threads_before == 1  # one I/O thread, none per client
    assert any("refused a connection" in e for e in server.events)
    for c in used:
        c.sock.close()
    _wait(lambda: not server.clients(), "the clients to go")
    ok = RawClient(server.port)  # the server serves again once there is room
    _handshake(ok)
    ok.sock.close()


def test_one_thread_serves_many_clients() -> None:
    with BridgeServer(port=0, max_clients=200) as s:
        before = threading.active_count()
        clients = [RawClient(s.port) for _ in range(100)]
        for c in clients:
            _handshake(c)
            c.command(wire.SUBSCRIBE, {"topic": "/all", "message_name": "std_msgs/String"})
        s.wait_for_subscribers("/all", 100)
        assert threading.active_count() == before
        assert s.publish("/all", b"payload") == 100
        for c in clients:
            assert c.read() == ("/all", b"payload")
            c.sock.close()


def test_silent_unused_connections_give_their_slots_to_new_clients() -> None:
    """Idle sockets no longer hold every slot: a well-behaved client still gets served."""
    with BridgeServer(port=0, max_clients=3, evict_silent=0.2) as s:
        idle = [RawClient(s.port) for _ in range(3)]
        for c in idle:
            _handshake(c)
        time.sleep(0.3)
        t0 = time.monotonic()
        good = RawClient(s.port)
        _handshake(good)
        assert time.monotonic() - t0 < 1.0
        good.command(wire.SUBSCRIBE, {"topic": "/g", "message_name": "std_msgs/String"})
        s.wait_for_subscribers("/g")
        assert s.evicted == 1 and s.refused == 0
        reasons = [c.closed_reason for c in s.closed_clients()]
        assert len(reasons) == 1 and reasons[0].startswith("evicted:")
        assert "registered nothing" in reasons[0]


def test_unused_and_idle_timeouts_close_with_the_reason() -> None:
    with BridgeServer(port=0, unused_timeout=0.3) as s:
        unused, used = RawClient(s.port), RawClient(s.port)
        _handshake(unused)
        _handshake(used)
        used.command(wire.SUBSCRIBE, {"topic": "/x", "message_name": "std_msgs/String"})
        assert _closed_by_server(unused.sock)
        _wait(lambda: len(s.clients()) == 1, "the unused client to be closed")
        assert "registered nothing within 0.3 s" in s.closed_clients()[0].closed_reason
        assert s.subscriber_count("/x") == 1
        # a client that only sends keepalives (and registers later) is in use: kept
        late = RawClient(s.port)
        _handshake(late)
        for _ in range(6):
            late.send_raw(wire.KEEPALIVE)
            time.sleep(0.1)
        late.command(wire.SUBSCRIBE, {"topic": "/late", "message_name": "std_msgs/String"})
        s.wait_for_subscribers("/late")
    with BridgeServer(port=0, idle_timeout=0.4, unused_timeout=None) as s:
        talking, silent = RawClient(s.port), RawClient(s.port)
        _handshake(talking)
        _handshake(silent)
        for _ in range(8):  # keepalives every 0.1 s keep a connection open
            talking.send_raw(wire.KEEPALIVE)
            time.sleep(0.1)
        assert _closed_by_server(silent.sock)
        _wait(lambda: len(s.clients()) == 1, "the silent client to be closed")
        reasons = [c.closed_reason for c in s.closed_clients()]
        assert len(reasons) == 1 and reasons[0].startswith("idle for ")
        assert "idle timeout of 0.4 s" in reasons[0]
    with pytest.raises(BridgeError, match="idle timeout must be a positive number"):
        BridgeServer(port=0, idle_timeout=float("nan"))


def test_oversized_system_commands_close_only_that_client(server: BridgeServer) -> None:
    good = RawClient(server.port)
    _handshake(good)
    for dest in (wire.SUBSCRIBE, wire.LOG):
        bad = RawClient(server.port)
        _handshake(bad)
        bad.send(dest, b"x" * (wire.MAX_COMMAND_BYTES + 1))
        assert _closed_by_server(bad.sock)
    _wait(lambda: len(server.closed_clients()) == 2, "two closed clients")
    reasons = [c.closed_reason for c in server.closed_clients()]
    assert all("system command payload" in r and "exceeds the cap" in r for r in reasons)
    good.command(wire.SUBSCRIBE, {"topic": "/ok", "message_name": "geometry_msgs/PoseStamped"})
    server.wait_for_subscribers("/ok")


def test_long_names_and_too_many_registrations_get_an_error(server: BridgeServer) -> None:
    c = RawClient(server.port)
    _handshake(c)
    c.command(wire.SUBSCRIBE, {"topic": "/" + "t" * 2000, "message_name": "std_msgs/String"})
    dest, body = c.read()
    assert dest == wire.ERROR and b"longer than 1024 bytes" in body
    for i in range(MAX_REGISTRATIONS + 1):
        c.command(wire.SUBSCRIBE, {"topic": f"/t{i}", "message_name": "std_msgs/String"})
    dest, body = c.read()
    assert dest == wire.ERROR and f"more than {MAX_REGISTRATIONS} registrations".encode() in body
    assert server.subscriber_count(f"/t{MAX_REGISTRATIONS - 1}") == 1
    assert server.subscriber_count(f"/t{MAX_REGISTRATIONS}") == 0


def test_log_texts_are_cut_in_the_events(server: BridgeServer) -> None:
    c = RawClient(server.port)
    _handshake(c)
    c.command(wire.LOG, {"text": "y" * 60_000})
    c.command(wire.SUBSCRIBE, {"topic": "/sync", "message_name": "std_msgs/String"})
    server.wait_for_subscribers("/sync")
    logged = [e for e in server.events if "yyyy" in e]
    assert len(logged) == 1 and len(logged[0]) < 400 and "characters)" in logged[0]


def test_closed_client_statistics_are_bounded() -> None:
    with BridgeServer(port=0, max_clients=8) as s:
        n = CLOSED_STATS_KEPT + 20
        PORT[0] = s.port
        for _ in range(n):
            sock = _connect()
            if sock is not None:
                sock.close()
            _wait(lambda: len(s.clients()) < 8, "room for the next client")
        _wait(lambda: s.closed_count + s.refused == n and not s.clients(), "every close")
        assert len(s.closed_clients()) == min(CLOSED_STATS_KEPT, s.closed_count)


_FD_STARVED_SERVER = """
import resource, sys
resource.setrlimit(resource.RLIMIT_NOFILE, (40, 40))
from uwval.bridge.server import BridgeServer
s = BridgeServer(port=0, max_clients=1000, unused_timeout=None).start()
print(s.port, flush=True)
sys.stdin.read()  # until the test closes our stdin
print(sum("accept failed" in e for e in s.events), flush=True)
s.stop()
"""


def test_the_accept_loop_survives_running_out_of_descriptors() -> None:
    """The real failure was an accept thread that died; here the server process's descriptor
    limit (40) is far below the 80 connections made, so accept() meets EMFILE."""
    proc = subprocess.Popen(
        [sys.executable, "-c", _FD_STARVED_SERVER],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert proc.stdout is not None
        port = int(proc.stdout.readline())
        held = [socket.create_connection(("127.0.0.1", port), timeout=5) for _ in range(80)]
        time.sleep(0.5)  # the server meets EMFILE and pauses accepting
        for sock in held:
            sock.close()
        ok = RawClient(port)
        ok.sock.settimeout(10)
        _handshake(ok)  # served again once descriptors are free
        ok.sock.close()
        out, _ = proc.communicate("", timeout=20)
        assert int(out) >= 1  # EMFILE was really met
        assert proc.returncode == 0
    finally:
        if proc.poll() is None:
            proc.kill()


def test_a_failed_parser_is_freed_without_the_cyclic_gc() -> None:
    """A parser kept its ProtocolError, whose traceback held the parser and its buffer: a
    cycle only the cyclic GC freed, which kept hostile clients' buffers after they left."""
    import gc
    import weakref

    parser = wire.FrameParser()
    with pytest.raises(wire.ProtocolError, match="malformed frame at byte 0"):
        parser.feed(b"\xf0\xff\xff\xff" + b"x" * 100_000)
    with pytest.raises(wire.ProtocolError, match="malformed frame at byte 0"):
        parser.feed(b"more")  # still unusable, with the same reason
    ref = weakref.ref(parser)
    gc.disable()
    try:
        del parser
        assert ref() is None
    finally:
        gc.enable()


@pytest.mark.parametrize("keepalives", [False, True], ids=["silent", "keepalive_only"])
def test_64_registered_idle_connections_cannot_keep_a_good_client_out(keepalives: bool) -> None:
    """bridge serve's defaults (64 slots): 64 real sockets that each subscribe and then stay
    silent, or send only keepalives, hold every slot; a good client is still served (its
    subscription registered and a message delivered) within a few seconds."""
    from uwval.bridge.server import DEFAULT_MAX_CLIENTS

    with BridgeServer(port=0) as s:  # the defaults of bridge serve
        flood = [RawClient(s.port) for _ in range(DEFAULT_MAX_CLIENTS)]
        for i, c in enumerate(flood):
            _handshake(c)
            c.command(wire.SUBSCRIBE, {"topic": f"/f{i}", "message_name": "std_msgs/String"})
        _wait(lambda: len(s.clients()) == DEFAULT_MAX_CLIENTS, "the flood to register")
        stop = threading.Event()

        def keep_alive() -> None:  # every 0.5 s, as often as a Connector at most
            while not stop.wait(0.5):
                for c in flood:
                    with contextlib.suppress(OSError):
                        c.send_raw(wire.KEEPALIVE)

        pinger = threading.Thread(target=keep_alive, daemon=True)
        if keepalives:
            pinger.start()
        try:
            t0 = time.monotonic()
            served = False
            for _ in range(40):  # a Unity-like client retrying, bounded
                try:
                    good = RawClient(s.port)
                    _handshake(good)
                    good.command(wire.SUBSCRIBE, {"topic": "/g", "message_name": "std_msgs/String"})
                    s.wait_for_subscribers("/g", timeout=1.0)
                    assert s.publish("/g", b"hello") == 1
                    assert good.read() == ("/g", b"hello")
                    served = True
                    break
                except (OSError, EOFError, BridgeError):
                    time.sleep(0.25)
            assert served and time.monotonic() - t0 < 6.0, time.monotonic() - t0
        finally:
            stop.set()
            for c in flood:
                c.sock.close()
