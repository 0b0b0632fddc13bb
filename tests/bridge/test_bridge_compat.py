"""``bridge serve --compat real-endpoint`` behaves as Unity's ROS-TCP-Endpoint 0.7.0 where the
real one is stricter (issue 17), so that a Unity app tested against uwval does not break on
the real endpoint. Every scenario runs against uwval's server in that mode and, when
``UWVAL_ROS_TCP_ENDPOINT`` points to an export of the real endpoint (see
tests/test_ros_endpoint.py), against the real endpoint too, with the same expectation."""

from __future__ import annotations

import contextlib
import json
import socket
import struct
import time
from collections.abc import Iterator
from typing import Any

import pytest
from cli_runner import run_uwval

from uwval.bridge.errors import BridgeError
from uwval.bridge.server import BridgeServer

STRING = "std_msgs/String"


def _frame(dest: str, payload: bytes) -> bytes:
    d = dest.encode()
    return struct.pack("<I", len(d)) + d + struct.pack("<I", len(payload)) + payload


def _cmd(dest: str, params: Any) -> bytes:
    return _frame(dest, json.dumps(params).encode())


def _string_body(text: str) -> bytes:
    """A ROS 1 std_msgs/String body (uint32 length + bytes)."""
    raw = text.encode()
    return struct.pack("<I", len(raw)) + raw


class Peer:
    """A Unity-like peer on a blocking socket, reading whole frames."""

    def __init__(self, port: int) -> None:
        self.sock = socket.create_connection(("127.0.0.1", port), timeout=5)
        self.buf = b""
        dest, _ = self.read(5)
        assert dest == "__handshake"

    def send(self, data: bytes) -> None:
        self.sock.sendall(data)

    def read(self, timeout: float) -> tuple[str, bytes]:
        """The next frame; EOFError when the peer closed the connection."""
        self.sock.settimeout(timeout)
        while True:
            if len(self.buf) >= 4:
                (dl,) = struct.unpack_from("<I", self.buf)
                if len(self.buf) >= 8 + dl:
                    (pl,) = struct.unpack_from("<I", self.buf, 4 + dl)
                    if len(self.buf) >= 8 + dl + pl:
                        dest = self.buf[4 : 4 + dl].decode().rstrip("\0")
                        body = self.buf[8 + dl : 8 + dl + pl]
                        self.buf = self.buf[8 + dl + pl :]
                        return dest, body
            try:
                chunk = self.sock.recv(65536)
            except ConnectionResetError:
                chunk = b""
            if not chunk:
                raise EOFError
            self.buf += chunk

    def closed_by_peer(self, timeout: float = 5.0) -> bool:
        deadline = time.monotonic() + timeout
        try:
            while time.monotonic() < deadline:
                self.read(max(0.01, deadline - time.monotonic()))
        except EOFError:
            return True
        except TimeoutError:
            return False
        return False

    def close(self) -> None:
        self.sock.close()


@pytest.fixture(params=["uwval", "real"])
def endpoint(request: pytest.FixtureRequest) -> Iterator[int]:
    """The port of uwval's server in real-endpoint mode, or of the real endpoint."""
    if request.param == "real":
        yield request.getfixturevalue("ros_endpoint").port
        return
    with BridgeServer(port=0, protocol="ROS1", compat="real-endpoint") as s:
        yield s.port


@pytest.mark.parametrize(
    "frame",
    [
        _cmd("__remove_subscriber", {"topic": "/x"}),  # not a command of 0.7.0
        _cmd("__nope", {}),
        _cmd("__handshake", {"version": "v0.7.0", "metadata": "{}"}),
        _cmd("__subscribe", {"topic": "/x", "message_name": STRING, "extra": 1}),
        _cmd("__subscribe", {"topic": "/x"}),
    ],
    ids=["remove_subscriber", "unknown", "client_handshake", "extra_key", "missing_key"],
)
def test_the_connection_closes_where_the_real_endpoint_closes_it(
    endpoint: int, frame: bytes
) -> None:
    peer = Peer(endpoint)
    try:
        peer.send(frame)
        assert peer.closed_by_peer()
    finally:
        peer.close()
    Peer(endpoint).close()  # the endpoint still serves


def test_unknown_message_class_gets_an_error_and_the_connection_stays(endpoint: int) -> None:
    peer = Peer(endpoint)
    try:
        peer.send(_cmd("__subscribe", {"topic": "/uwval_x", "message_name": "nope_msgs/Nope"}))
        dest, body = peer.read(5)
        assert dest == "__error"
        assert "Unknown message class 'nope_msgs/Nope'" in json.loads(body)["text"]
        peer.send(_cmd("__topic_list", {}))
        dest, body = peer.read(5)
        assert dest == "__topic_list"
        assert "/rosout" in json.loads(body)["topics"]  # the ROS graph's published topics
    finally:
        peer.close()


def _until_received(peer: Peer, send: bytes, topic: str, want: bytes) -> bool:
    """Send ``send`` every 0.1 s (ROS connects publishers and subscribers asynchronously)
    until a frame on ``topic`` with body ``want`` arrives, for up to 10 s."""
    deadline = time.monotonic() + 10
    while time.monotonic() < deadline:
        peer.send(send)
        try:
            while True:
                dest, body = peer.read(0.1)
                if dest == topic and body == want:
                    return True
        except TimeoutError:
            continue
    return False


def test_own_publications_come_back_and_registrations_outlive_the_connection(
    endpoint: int,
) -> None:
    topic = f"/uwval_echo_{time.monotonic_ns()}"
    first = Peer(endpoint)
    try:
        first.send(_cmd("__subscribe", {"topic": topic, "message_name": STRING}))
        first.send(_cmd("__publish", {"topic": topic, "message_name": STRING}))
        body = _string_body("echo")
        assert _until_received(first, _frame(topic, body), topic, body)
    finally:
        first.close()
    time.sleep(0.3)
    # a new connection that registers nothing: the endpoint's publisher and subscriber remain
    second = Peer(endpoint)
    try:
        body = _string_body("kept")
        assert _until_received(second, _frame(topic, body), topic, body)
    finally:
        second.close()


def test_uwval_mode_stays_forgiving() -> None:
    with BridgeServer(port=0) as s:
        peer = Peer(s.port)
        try:
            peer.send(_cmd("__remove_subscriber", {"topic": "/x"}))
            dest, body = peer.read(5)
            assert dest == "__error" and "Don't understand" in json.loads(body)["text"]
            peer.send(_cmd("__subscribe", {"topic": "/x", "message_name": "nope_msgs/Nope"}))
            peer.send(_cmd("__topic_list", {}))
            assert peer.read(5)[0] == "__topic_list"
            assert s.subscriber_count("/x") == 1
        finally:
            peer.close()


def test_bridge_serve_compat_option_is_checked() -> None:
    result = run_uwval("bridge", "serve", "--compat", "nope", "--port", "0")
    assert result.returncode == 2
    want = "--compat must be one of uwval, real-endpoint, real-endpoint-subscribers"
    assert want in result.stdout + result.stderr
    assert "Traceback" not in result.stderr


POSE = "geometry_msgs/PoseStamped"


def _pose(k: int, seq: int) -> bytes:
    from uwval.bridge.protocol import encode_pose_stamped

    return encode_pose_stamped(10**9 + k, [k, 0.0, 0.0], [0, 0, 0, 1.0], "world", "ROS1", seq)


def _echo(peer: Peer, topic: str) -> None:
    """Subscribe and publish ``topic`` (PoseStamped) until the endpoint echoes a pose back."""
    peer.send(_cmd("__subscribe", {"topic": topic, "message_name": POSE}))
    peer.send(_cmd("__publish", {"topic": topic, "message_name": POSE}))
    deadline = time.monotonic() + 10
    while time.monotonic() < deadline:
        peer.send(_frame(topic, _pose(0, 777)))
        try:
            while True:
                if peer.read(0.1)[0] == topic:
                    return
        except TimeoutError:
            continue
    raise AssertionError(f"{topic} never came back")


def _drain(peer: Peer, seconds: float) -> list[tuple[str, bytes]]:
    got = []
    with contextlib.suppress(TimeoutError):
        while True:
            got.append(peer.read(seconds))
    return got


def test_header_seq_is_rewritten_as_rospy_does(endpoint: int) -> None:
    """A pose a client publishes reaches ROS with header.seq = the publisher's count (rospy),
    whatever seq the client sent: what comes back counts up by one per message."""
    topic = f"/uwval_seq_{time.monotonic_ns()}"
    peer = Peer(endpoint)
    try:
        _echo(peer, topic)
        _drain(peer, 0.3)
        for k in range(1, 6):
            peer.send(_frame(topic, _pose(k, 777)))
        back = [b for d, b in _drain(peer, 1.0) if d == topic]
        assert len(back) == 5
        seqs = [struct.unpack_from("<I", b)[0] for b in back]
        assert 777 not in seqs and seqs == list(range(seqs[0], seqs[0] + 5)), seqs
        assert [b[4:] for b in back] == [_pose(k, 0)[4:] for k in range(1, 6)]  # the rest kept
    finally:
        peer.close()


def test_everything_goes_to_the_newest_connection(endpoint: int) -> None:
    """ROS-TCP-Endpoint 0.7.0 has one sender queue, the newest connection's: once a second
    client connects, the first one's subscription is served to the second, not to it."""
    topic = f"/uwval_newest_{time.monotonic_ns()}"
    first = Peer(endpoint)
    try:
        _echo(first, topic)
        _drain(first, 0.3)
        second = Peer(endpoint)  # registers nothing
        try:
            time.sleep(0.3)
            first.send(_frame(topic, _pose(9, 0)))
            assert [d for d, _ in _drain(second, 1.0)] == [topic]
            assert _drain(first, 0.3) == []
        finally:
            second.close()
    finally:
        first.close()


def test_compat_real_endpoint_announces_ros1_itself() -> None:
    with BridgeServer(port=0, compat="real-endpoint") as s:
        sock = socket.create_connection(("127.0.0.1", s.port), timeout=5)
        try:
            peer = Peer.__new__(Peer)
            peer.sock, peer.buf = sock, b""
            dest, body = peer.read(5)
            meta = json.loads(json.loads(body)["metadata"])
            assert dest == "__handshake" and meta == {"protocol": "ROS1"}
        finally:
            sock.close()
        assert (s.protocol, s.route) == ("ROS1", "newest")
    res = run_uwval(
        "bridge", "serve", "--compat", "real-endpoint", "--port", "0", "--duration", "0.3"
    )
    assert res.returncode == 0, res.stderr
    assert "(ROS1, as ROS-TCP-Endpoint 0.7.0, to newest)" in " ".join(res.stderr.split())
    res = run_uwval(
        "bridge", "serve", "--compat", "real-endpoint-subscribers", "--port", "0",
        "--duration", "0.3",
    )  # fmt: skip
    assert "(ROS1, as ROS-TCP-Endpoint 0.7.0, to subscribers)" in " ".join(res.stderr.split())
    with pytest.raises(BridgeError, match="newest only with compat real-endpoint"):
        BridgeServer(port=0, route="newest")
