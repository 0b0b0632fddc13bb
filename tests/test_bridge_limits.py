"""Issue 14: the bridge server under hostile clients keeps bounded connections, threads and
memory, refuses oversized system commands and names, and its accept loop never dies.
Loopback only, bounded loops (a measurement with 10,000 connections is
benchmarks/bridge_hostile.py)."""

from __future__ import annotations

import socket
import threading
import time
from collections.abc import Iterator

import pytest

from tests.test_bridge_server import RawClient
from uwval.bridge import protocol as wire
from uwval.bridge import server as server_mod
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


def _client_threads() -> int:
    """Reader and writer threads of bridge servers in this process."""
    return sum(t.name.startswith(("bridge-read", "bridge-write")) for t in threading.enumerate())


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
    idle = [RawClient(server.port) for _ in range(3)]
    for c in idle:
        _handshake(c)
    # each accepted client has a reader and a writer thread; count once all have started
    _wait(lambda: _client_threads() >= 2 * len(idle), "the idle clients' threads")
    threads_before = _client_threads()
    PORT[0] = server.port
    for _ in range(20):
        s = _connect()
        assert _closed_by_server(s)
        if s is not None:
            s.close()
    _wait(lambda: server.refused == 20, "20 refusals")
    assert len(server.clients()) == 3
    assert _client_threads() <= threads_before  # no thread for a refused connection
    assert any("refused a connection" in e for e in server.events)
    for c in idle:
        c.sock.close()
    _wait(lambda: not server.clients(), "the idle clients to go")
    ok = RawClient(server.port)  # the server serves again once there is room
    _handshake(ok)
    ok.sock.close()


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


def test_the_accept_loop_survives_a_thread_that_cannot_start(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """The real failure was RuntimeError("can't start new thread") under a memory limit."""
    failures = {"left": 1}
    real_thread = threading.Thread

    class Flaky(real_thread):  # type: ignore[misc, valid-type]
        def start(self) -> None:
            if self.name.startswith("bridge-write") and failures["left"]:
                failures["left"] -= 1
                raise RuntimeError("can't start new thread")
            super().start()

    monkeypatch.setattr(server_mod.threading, "Thread", Flaky)
    with BridgeServer(port=0) as s:
        PORT[0] = s.port
        assert _closed_by_server(_connect())
        _wait(lambda: s.closed_count == 1, "the failed client to be closed")
        assert "cannot start its threads" in s.closed_clients()[0].closed_reason
        ok = RawClient(s.port)
        _handshake(ok)
        ok.sock.close()
