"""The endpoint (uwval.bridge.server) driven by a client written here from the protocol facts.

``RawClient`` deliberately does not use uwval.bridge.protocol: it frames bytes with struct, the
way DESIGN.md section 6 describes the wire (u32 LE length + destination, u32 LE length +
payload; 8 zero bytes = keepalive; Unity's ROS 2 trailing NULs).
"""

from __future__ import annotations

import contextlib
import itertools
import json
import struct
import time
from collections.abc import Iterator

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from raw_client import RawClient

from uwval.bridge.errors import BridgeError
from uwval.bridge.server import BridgeServer


@pytest.fixture
def server() -> Iterator[BridgeServer]:
    srv = BridgeServer("127.0.0.1", 0, queue_size=64).start()
    yield srv
    srv.stop()


def _connected(server: BridgeServer, topic: str, nul: bool = True) -> RawClient:
    before = server.subscriber_count(topic)
    c = RawClient(server.port, nul=nul)
    c.handshake()
    c.send_raw(b"\x00" * 8)  # Unity's keepalive on connect
    c.subscribe(topic)
    server.wait_for_subscribers(topic, before + 1, timeout=5)
    return c


def test_default_address_is_loopback_10000() -> None:
    srv = BridgeServer()
    assert srv.address == ("127.0.0.1", 10000)


def test_handshake_then_subscribed_topic_delivery(server: BridgeServer) -> None:
    c = RawClient(server.port)
    params = c.handshake()
    assert params["version"] == "v0.7.0"
    assert json.loads(str(params["metadata"])) == {"protocol": "ROS2"}
    c.send_raw(b"\x00" * 8)
    c.subscribe("model_rov_pose")
    server.wait_for_subscribers("model_rov_pose", 1)
    body = b"\x00\x01\x00\x00" + bytes(range(40))
    assert server.publish("model_rov_pose", body) == 1
    assert server.publish("other_topic", b"zz") == 0  # nobody subscribed
    assert c.read() == ("model_rov_pose", body)
    c.close()


def test_ros1_endpoint_announces_ros1() -> None:
    with BridgeServer("127.0.0.1", 0, protocol="ROS1") as srv:
        c = RawClient(srv.port, nul=False)
        assert json.loads(str(c.handshake()["metadata"])) == {"protocol": "ROS1"}
        c.close()


def test_commands_without_trailing_nul_are_accepted(server: BridgeServer) -> None:
    c = _connected(server, "a", nul=False)
    server.publish("a", b"x")
    assert c.read() == ("a", b"x")


def test_unity_publishes_to_ros_side_and_to_other_clients(server: BridgeServer) -> None:
    got: list[tuple[str, bytes, int]] = []
    server.on_topic("cmd", lambda t, b, cid: got.append((t, b, cid)))
    listener = _connected(server, "cmd")
    talker = RawClient(server.port)
    talker.handshake()
    talker.command(
        "__publish",
        {"topic": "cmd", "message_name": "std_msgs/Header", "queue_size": 10, "latch": False},
    )
    talker.send("cmd", b"payload-1")
    assert listener.read() == ("cmd", b"payload-1")
    deadline = time.monotonic() + 5
    while not got and time.monotonic() < deadline:
        time.sleep(0.005)
    assert got
    assert got[0][:2] == ("cmd", b"payload-1")
    # Publishing on a topic that was not registered gets an __error back, as the endpoint does.
    talker.send("unregistered", b"zz")
    dest, params = talker.read_json()
    assert dest == "__error"
    assert "Not registered to publish topic 'unregistered'" in str(params["text"])


def test_topic_list_lists_advertised_and_unity_topics(server: BridgeServer) -> None:
    server.advertise("model_rov_pose", "geometry_msgs/msg/PoseStamped")
    c = RawClient(server.port)
    c.handshake()
    c.command("__publish", {"topic": "from_unity", "message_name": "std_msgs/Header"})
    c.command("__topic_list", {})
    dest, params = c.read_json()
    assert dest == "__topic_list"
    assert params == {
        "topics": ["from_unity", "model_rov_pose"],
        "types": ["std_msgs/Header", "geometry_msgs/PoseStamped"],
    }


def test_ros_service_request_response(server: BridgeServer) -> None:
    server.add_service("double", lambda req: req * 2)
    c = RawClient(server.port)
    c.handshake()
    c.command("__ros_service", {"topic": "double", "message_name": "x/Double"})
    c.command("__request", {"srv_id": 7})
    c.send("double", b"ab")
    dest, params = c.read_json()
    assert (dest, params) == ("__response", {"srv_id": 7})
    assert c.read() == ("double", b"abab")
    c.command("__request", {"srv_id": 8})
    c.send("missing", b"")
    dest, params = c.read_json()
    assert dest == "__error"
    assert "'missing' is not registered" in str(params["text"])


def test_unity_service_called_from_ros_side(server: BridgeServer) -> None:
    import threading

    c = RawClient(server.port)
    c.handshake()
    c.command("__unity_service", {"topic": "get_pose", "message_name": "x/GetPose"})
    server.wait_for_registration("get_pose", "unity_service")
    result: list[bytes] = []
    t = threading.Thread(
        target=lambda: result.append(server.call_unity_service("get_pose", b"req", timeout=5))
    )
    t.start()
    dest, params = c.read_json()
    assert dest == "__request"
    srv_id = params["srv_id"]
    assert c.read() == ("get_pose", b"req")
    c.command("__response", {"srv_id": srv_id})
    c.send("get_pose", b"resp")
    t.join(5)
    assert result == [b"resp"]
    with pytest.raises(BridgeError, match="no connected client offers Unity service 'nope'"):
        server.call_unity_service("nope", b"")


def test_log_commands_and_unknown_command(server: BridgeServer) -> None:
    c = RawClient(server.port)
    c.handshake()
    c.command("__warn", {"text": "low fps"})
    c.command("__frobnicate", {})
    dest, params = c.read_json()
    assert dest == "__error"
    assert "__frobnicate" in str(params["text"])
    assert any("low fps" in e for e in server.events)
    server.send_log("warn", "hello unity")
    assert c.read_json() == ("__warn", {"text": "hello unity"})


def test_malformed_frame_closes_only_that_client(server: BridgeServer) -> None:
    good = _connected(server, "t")
    bad = RawClient(server.port)
    bad.handshake()
    bad.send_raw(struct.pack("<I", 1) + b"x" + struct.pack("<I", server.max_frame + 1))
    with pytest.raises((EOFError, ConnectionResetError)):
        bad.read()
    reasons = [c.closed_reason for c in server.closed_clients()]
    assert any("payload length" in r and "at byte 0" in r for r in reasons), reasons
    server.publish("t", b"still-served")
    assert good.read() == ("t", b"still-served")


def test_bad_json_closes_client_with_reason(server: BridgeServer) -> None:
    c = RawClient(server.port)
    c.handshake()
    c.send("__subscribe", b"{not json")
    with pytest.raises((EOFError, ConnectionResetError)):
        c.read()
    assert any("invalid JSON" in s.closed_reason for s in server.closed_clients())


def test_bounded_queue_drops_oldest_and_counts(server: BridgeServer) -> None:
    slow = RawClient(server.port)
    slow.handshake()
    slow.subscribe("flood")
    server.wait_for_subscribers("flood", 1)
    n = 400

    def body(k: int) -> bytes:
        return struct.pack("<I", k) + bytes([k % 251]) * 60_000

    for k in range(n):  # ~24 MB: far beyond socket buffers and the 64-item queue
        server.publish("flood", body(k))
    stats = next(s for s in server.clients() if "flood" in s.subscriptions)
    assert stats.dropped > 0
    # Drain: frames arrive whole and in order (a drop never splits a frame, even when a
    # frame was partly sent directly), the newest is never dropped, and every published
    # frame was either received or counted as dropped.
    seqs: list[int] = []
    while not seqs or seqs[-1] != n - 1:
        dest, payload = slow.read()
        assert dest == "flood"
        k = struct.unpack_from("<I", payload)[0]
        assert payload == body(k)
        seqs.append(k)
    assert seqs == sorted(seqs)
    assert len(seqs) + stats.dropped == n


fuzz_chunks = st.one_of(
    st.binary(max_size=64),  # garbage
    st.builds(
        lambda d, p: struct.pack("<I", len(d)) + d + struct.pack("<I", len(p)) + p,
        st.binary(max_size=20),
        st.binary(max_size=50),
    ),  # well-formed, random bytes
    st.builds(
        lambda n: struct.pack("<I", 1) + b"a" + struct.pack("<I", n),
        st.integers(min_value=0, max_value=2**32 - 1),
    ),  # any (oversized) length
    st.builds(lambda d: struct.pack("<I", len(d)) + d, st.binary(max_size=20)),  # truncated
    st.builds(  # system commands with arbitrary (often wrong) JSON or bytes
        lambda cmd, body, nul: (
            lambda d, p: struct.pack("<I", len(d)) + d + struct.pack("<I", len(p)) + p
        )(cmd.encode() + (b"\x00" if nul else b""), body),
        st.sampled_from(
            [
                "__subscribe",
                "__publish",
                "__ros_service",
                "__unity_service",
                "__request",
                "__response",
                "__topic_list",
                "__log",
                "__warn",
                "__error",
                "__handshake",
                "__nope",
            ]
        ),
        st.one_of(
            st.binary(max_size=30),
            st.recursive(
                st.none() | st.booleans() | st.floats() | st.integers() | st.text(max_size=8),
                lambda kids: (
                    st.lists(kids, max_size=3)
                    | st.dictionaries(
                        st.sampled_from(["topic", "message_name", "srv_id", "text", "latch"]),
                        kids,
                        max_size=4,
                    )
                ),
                max_leaves=6,
            ).map(lambda v: json.dumps(v).encode()),
        ),
        st.booleans(),
    ),
)


_fuzz_ids = itertools.count()


@settings(
    max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(chunks=st.lists(fuzz_chunks, min_size=1, max_size=8))
def test_fuzzed_client_never_hurts_the_server_or_other_clients(
    server: BridgeServer, chunks: list[bytes]
) -> None:
    topic = f"fuzz_target_{next(_fuzz_ids)}"  # fresh topic: stale clients never count
    good = _connected(server, topic)
    evil = RawClient(server.port)
    sent = []
    for ch in chunks:
        with contextlib.suppress(OSError):  # the server may have closed the fuzzing client
            evil.send_raw(ch)
        sent.append(ch[:16] + b"!")
        server.publish(topic, sent[-1])
    evil.close()
    for body in sent:
        assert good.read() == (topic, body)
    # The server still accepts and serves a new client.
    fresh = _connected(server, topic)
    server.publish(topic, b"after")
    assert fresh.read() == (topic, b"after")
    assert good.read() == (topic, b"after")
    good.close()
    fresh.close()
    # Every client the server closed was closed for a protocol reason, never a crash.
    assert not [
        c.closed_reason
        for c in server.closed_clients()
        if c.closed_reason.startswith("internal error")
    ]


def test_message_names_must_be_pkg_type(server: BridgeServer) -> None:
    c = RawClient(server.port)
    c.handshake()
    c.command("__subscribe", {"topic": "t", "message_name": "geometry_msgs/msg/PoseStamped"})
    dest, params = c.read_json()
    assert dest == "__error"
    assert "Unknown message class 'geometry_msgs/msg/PoseStamped'" in str(params["text"])
    assert server.subscriber_count("t") == 0
    c.command("__subscribe", {"topic": "", "message_name": "geometry_msgs/PoseStamped"})
    dest, params = c.read_json()
    assert dest == "__error"
    assert "blank topic" in str(params["text"])


def _raw_frame(c: RawClient) -> tuple[bytes, bytes]:
    """One frame exactly as sent (destination and payload bytes, NULs kept)."""
    (dlen,) = struct.unpack("<I", c._exact(4))
    dest = c._exact(dlen)
    (plen,) = struct.unpack("<I", c._exact(4))
    return dest, c._exact(plen)


@pytest.mark.parametrize("nul", [True, False])
def test_replies_never_carry_nuls(server: BridgeServer, nul: bool) -> None:
    """A ROS 2 Unity appends NULs and a ROS 1 one does not: both are accepted on the way in,
    but the endpoint never sends one (Unity's ROSConnection matches the destination string
    exactly, so '__error\0' would be silently ignored, as ROS-TCP-Endpoint never sends it)."""
    c = RawClient(server.port, nul=nul)
    dest, payload = _raw_frame(c)
    assert dest == b"__handshake"
    c.command("__frobnicate", {})
    dest, payload = _raw_frame(c)
    assert dest == b"__error"
    assert payload.endswith(b"}")
    assert "__frobnicate" in json.loads(payload)["text"]
    server.send_log("warn", "hello")
    assert _raw_frame(c) == (b"__warn", b'{"text":"hello"}')
    c.close()
