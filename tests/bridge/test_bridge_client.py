"""The Unity-like client on real sockets: handshake checks, reconnects, replay end to end."""

from __future__ import annotations

import json
import os
import socket
import struct
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from uwval.bridge import protocol as wire
from uwval.bridge.errors import BridgeError
from uwval.bridge.recorder import BridgeRecorder, open_mcap_writer
from uwval.bridge.server import BridgeServer
from uwval.bridge.unity_client import AppliedTransform, FaultModel, UnityClient, UnityConnection

REPO = Path(__file__).resolve().parents[2]


def fake_endpoint(handshake: dict[str, str]) -> tuple[int, threading.Thread]:
    """A one-shot endpoint that sends the given handshake JSON (struct framing by hand)."""
    srv = socket.socket()
    srv.bind(("127.0.0.1", 0))
    srv.listen(1)

    def serve() -> None:
        conn, _ = srv.accept()
        d, p = b"__handshake", json.dumps(handshake).encode()
        conn.sendall(struct.pack("<I", len(d)) + d + struct.pack("<I", len(p)) + p)
        time.sleep(0.3)
        conn.close()
        srv.close()

    t = threading.Thread(target=serve, daemon=True)
    t.start()
    return srv.getsockname()[1], t


def test_client_rejects_other_versions_and_protocols() -> None:
    port, t = fake_endpoint({"version": "v0.6.0", "metadata": '{"protocol": "ROS2"}'})
    with pytest.raises(BridgeError, match=r"unsupported ROS-TCP version 'v0\.6\.0'"):
        UnityConnection("127.0.0.1", port).connect(timeout=5)
    t.join()
    with (
        BridgeServer("127.0.0.1", 0, protocol="ROS1") as srv,
        pytest.raises(BridgeError, match="speaks ROS1, this client was built for ROS2"),
    ):
        UnityConnection("127.0.0.1", srv.port, protocol="ROS2").connect()
    with pytest.raises(BridgeError, match=r"cannot connect to 127\.0\.0\.1"):
        UnityConnection("127.0.0.1", 1).connect(timeout=1)


def test_connection_registers_with_unity_nuls_and_gets_topic_list() -> None:
    with BridgeServer("127.0.0.1", 0) as srv:
        srv.advertise("model_rov_pose", wire.POSE_STAMPED)
        conn = UnityConnection(
            "127.0.0.1",
            srv.port,
            subscriptions={"model_rov_pose": wire.POSE_STAMPED},
            publications={"unity_clicks": "std_msgs/Header"},
        )
        conn.connect()
        assert conn.server_version == "v0.7.0"
        srv.wait_for_subscribers("model_rov_pose")
        srv.wait_for_registration("unity_clicks", "publish")
        conn.send_command(wire.TOPIC_LIST)
        deadline = time.monotonic() + 5
        while not conn.commands and time.monotonic() < deadline:
            conn.poll(0.1)
        reply = conn.commands[0].json()
        assert reply["topics"] == ["model_rov_pose", "unity_clicks"]
        conn.close()


def _publisher(srv: BridgeServer, stop: threading.Event) -> None:
    k = 0
    while not stop.is_set():
        t_ns = time.monotonic_ns()
        for topic in ("model_rov_pose", "gui_camera_pose"):
            srv.publish(
                topic,
                wire.encode_pose_stamped(t_ns, [k * 0.01, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0], "world"),
            )
        k += 1
        time.sleep(0.005)


@pytest.fixture
def live_server() -> Iterator[BridgeServer]:
    srv = BridgeServer("127.0.0.1", 0).start()
    stop = threading.Event()
    pub = threading.Thread(target=_publisher, args=(srv, stop), daemon=True)
    pub.start()
    yield srv
    stop.set()
    pub.join()
    srv.stop()


def test_client_reconnects_after_delay_and_reregisters(live_server: BridgeServer) -> None:
    srv = live_server
    client = UnityClient(
        "127.0.0.1",
        srv.port,
        frame_rate=60.0,
        reconnect_delay_s=0.3,
        faults=FaultModel(latency_s=0.02),
    )
    applied = []

    def kick() -> None:
        srv.wait_for_subscribers("model_rov_pose", 1)
        time.sleep(0.6)
        cid = srv.clients()[0].client_id
        srv.disconnect(cid, "test kicks the client")

    kicker = threading.Thread(target=kick)
    kicker.start()
    applied = client.run_realtime(2.0)
    kicker.join()
    assert client.disconnects == 1
    assert client.connection.connects == 2
    closed = srv.closed_clients()
    assert closed[0].closed_reason == "test kicks the client"
    subscribes = [e for e in srv.events if "__subscribe model_rov_pose" in e]
    assert len(subscribes) == 2  # registered again after the reconnect
    stamps = np.array([a.applied_stamp_ns for a in applied if a.topic == "model_rov_pose"])
    times = np.array([a.frame_t_ns for a in applied if a.topic == "model_rov_pose"])
    # Poses keep flowing after the reconnect: fresh stamps near the end of the run.
    assert times[-1] - stamps[-1] < 300_000_000
    # Latency: nothing applied before it could have arrived.
    assert np.all(times - stamps >= 20_000_000)


def test_replay_cli_drives_a_unity_client(tmp_path: Path) -> None:
    log = tmp_path / "gz.mcap"
    rec = BridgeRecorder(open_mcap_writer(log))
    q = np.array([0.0, 0.0, 0.0, 1.0])
    for k in range(100):  # 2 s at 50 Hz
        for name in ("model_rov_pose", "gui_camera_pose"):
            rec.gazebo_pose(name, 1_000_000_000 + k * 20_000_000, np.array([k, 1.0, 2.0]), q)
    rec.close()
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    env = dict(os.environ, PYTHONPATH=str(REPO))
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "uwval",
            "bridge",
            "replay",
            str(log),
            "--port",
            str(port),
            "--speed",
            "4",
            "--wait",
            "30",
        ],
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    try:
        client = UnityClient("127.0.0.1", port, reconnect_delay_s=0.2)
        last = 1_000_000_000 + 99 * 20_000_000
        done = threading.Event()

        def on_frame(tr: AppliedTransform) -> None:
            if tr.applied_stamp_ns == last:
                done.set()

        # Long limit for a loaded machine; the client stops once the last pose showed.
        applied = client.run_realtime(60.0, on_frame=on_frame, connect_timeout=1.0, stop=done)
        out, _ = proc.communicate(timeout=30)
    finally:
        proc.kill()
    assert proc.returncode == 0, out
    assert "replayed 100 ticks" in out
    got = {a.applied_stamp_ns: a.position for a in applied if a.topic == "model_rov_pose"}
    assert max(got) == 1_000_000_000 + 99 * 20_000_000  # the whole log went through
    for stamp, pos_u in got.items():  # Unity FLU map: ROS (x, y, z) -> Unity (-y, z, x)
        k = (stamp - 1_000_000_000) // 20_000_000
        np.testing.assert_allclose(pos_u, [-1.0, 2.0, float(k)])


def test_replay_cli_missing_log_is_a_clean_error(tmp_path: Path) -> None:
    env = dict(os.environ, PYTHONPATH=str(REPO))
    res = subprocess.run(
        [
            sys.executable,
            "-m",
            "uwval",
            "bridge",
            "replay",
            str(tmp_path / "nope.mcap"),
            "--port",
            "0",
        ],
        env=env,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert res.returncode == 2
    assert "nope.mcap: no such file or directory" in res.stderr


def test_idle_client_sends_keepalives_that_the_server_ignores() -> None:
    with BridgeServer("127.0.0.1", 0) as srv:
        conn = UnityConnection("127.0.0.1", srv.port, subscriptions={"a": wire.POSE_STAMPED})
        conn.connect()
        srv.wait_for_subscribers("a")
        before = srv.clients()[0].frames_in  # keepalive on connect + __subscribe
        assert before == 2
        conn.keepalive_if_idle(interval=0.0)
        conn.keepalive_if_idle(interval=3600.0)  # not idle that long: nothing sent
        deadline = time.monotonic() + 5
        while srv.clients()[0].frames_in == before and time.monotonic() < deadline:
            time.sleep(0.01)
        assert srv.clients()[0].frames_in == before + 1
        assert srv.clients()[0].closed_reason == ""
        conn.close()


def test_serve_cli_accepts_a_client(tmp_path: Path) -> None:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    env = dict(os.environ, PYTHONPATH=str(REPO))
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "uwval",
            "bridge",
            "serve",
            "--port",
            str(port),
            "--duration",
            "30",
            "--protocol",
            "ros1",
        ],
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    try:
        deadline = time.monotonic() + 30
        conn = UnityConnection("127.0.0.1", port, protocol="ROS1")
        while True:
            try:
                conn.connect(timeout=1.0)
                break
            except BridgeError:
                if time.monotonic() > deadline or proc.poll() is not None:
                    raise
                time.sleep(0.2)
        assert conn.server_version == "v0.7.0"
        conn.close()
    finally:
        proc.terminate()
        proc.wait(10)


def test_injected_link_drop_then_unity_like_reconnect(live_server: BridgeServer) -> None:
    client = UnityClient(
        "127.0.0.1", live_server.port, reconnect_delay_s=0.3, faults=FaultModel(disconnects=[0.4])
    )
    applied = client.run_realtime(1.5)
    assert client.disconnects == 1
    assert client.connection.connects == 2
    times = np.array([a.frame_t_ns for a in applied if a.topic == "model_rov_pose"])
    stamps = np.array([a.applied_stamp_ns for a in applied if a.topic == "model_rov_pose"])
    # Frozen while offline: one stamp held for about the 0.3 s reconnect delay...
    change = np.flatnonzero(np.diff(stamps)) + 1
    starts = np.concatenate(([0], change))
    ends = np.concatenate((change, [len(stamps)])) - 1
    spans = times[ends] - times[starts]
    longest = int(np.argmax(spans))
    assert spans[longest] >= 250_000_000
    # ...then fresh poses again after reconnecting.
    assert ends[longest] < len(stamps) - 1
    assert stamps[-1] > stamps[ends[longest]]


def test_unity_timings_are_ros_tcp_connectors() -> None:
    """Keepalive after 1 s without sending, reconnect 1 s after a lost link (DESIGN.md 6)."""
    from uwval.bridge import unity_client as uc

    assert uc.KEEPALIVE_INTERVAL_S == 1.0
    assert uc.RECONNECT_DELAY_S == 1.0
    from uwval.bridge.options import RECONNECT_DELAY_S

    assert RECONNECT_DELAY_S == uc.RECONNECT_DELAY_S
    assert UnityClient().reconnect_delay_s == 1.0
    assert FaultModel().reconnect_delay_s == 1.0


def test_render_loop_sends_one_keepalive_per_idle_second() -> None:
    """Nothing to send for ~1.6 s: exactly one keepalive, at about 1 s (not one per frame)."""
    with BridgeServer("127.0.0.1", 0) as srv:
        client = UnityClient("127.0.0.1", srv.port, topics=("a",))
        seen: dict[str, int] = {}

        def sample() -> None:
            srv.wait_for_subscribers("a")
            t_reg = time.monotonic()
            seen["registered"] = srv.clients()[0].frames_in  # keepalive + __subscribe
            time.sleep(max(0.0, t_reg + 0.7 - time.monotonic()))
            seen["at_0.7s"] = srv.clients()[0].frames_in
            time.sleep(max(0.0, t_reg + 1.5 - time.monotonic()))
            seen["at_1.5s"] = srv.clients()[0].frames_in

        sampler = threading.Thread(target=sample)
        sampler.start()
        client.run_realtime(1.7)
        sampler.join()
        assert seen["registered"] == 2
        assert seen["at_0.7s"] == 2  # not idle for 1 s yet
        assert seen["at_1.5s"] == 3  # one keepalive
        # the endpoint took the keepalive as one (no protocol error closed the link)
        assert all("protocol" not in c.closed_reason for c in srv.closed_clients())


@pytest.mark.parametrize("speed", [1.0, 3.0])
def test_replay_paces_at_recorded_and_scaled_speed(tmp_path: Path, speed: float) -> None:
    """Recorded stamps go out unchanged; wall spacing is the recorded spacing / speed."""
    from uwval.bridge.replay import replay_log

    log = tmp_path / "gz.mcap"
    rec = BridgeRecorder(open_mcap_writer(log))
    q = np.array([0.0, 0.0, 0.0, 1.0])
    n, period_ns = 31, 20_000_000  # 0.6 s at 50 Hz
    for k in range(n):
        rec.gazebo_pose("model_rov_pose", 5_000_000_000 + k * period_ns, np.array([k, 0.0, 0.0]), q)
    rec.close()
    with BridgeServer("127.0.0.1", 0) as srv:
        conn = UnityConnection(
            "127.0.0.1", srv.port, subscriptions={"model_rov_pose": wire.POSE_STAMPED}
        )
        conn.connect()
        arrivals: list[tuple[int, int]] = []  # (wall ns, header stamp ns)

        def receive() -> None:
            deadline = time.monotonic() + 30
            while len(arrivals) < n and time.monotonic() < deadline:
                for f in conn.poll(0.05):
                    stamp = wire.decode_pose_stamped(f.payload, "ROS2")[0]
                    arrivals.append((time.monotonic_ns(), stamp))

        reader = threading.Thread(target=receive)
        reader.start()
        stats = replay_log(
            log, srv, topics=["/gazebo/model_rov_pose"], speed=speed, wait_for_subscriber_s=5
        )
        reader.join()
        conn.close()
    assert stats.ticks == stats.published == stats.delivered == n
    assert stats.log_duration_s == pytest.approx(0.6)
    stamps = np.array([s for _, s in arrivals])
    np.testing.assert_array_equal(stamps, 5_000_000_000 + np.arange(n) * period_ns)
    wall = np.array([w for w, _ in arrivals], dtype=np.float64) * 1e-9
    expected = 0.6 / speed
    # sleeping never ends early: the pass takes at least the scaled log duration...
    assert stats.wall_time_s >= 0.97 * expected
    assert wall[-1] - wall[0] >= 0.95 * expected
    # ...and the typical spacing is the scaled recorded one (median: robust to load)
    assert float(np.median(np.diff(wall))) == pytest.approx(0.02 / speed, rel=0.25)


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        (("serve", "--port", "99999"), "--port"),
        (("serve", "--port", "0", "--duration", "nan"), "--duration"),
        (("serve", "--port", "0", "--queue-size", "0"), "queue size"),
        (("serve", "--port", "0", "--max-frame", "-5"), "max frame"),
        (("serve", "--port", "0", "--protocol", "ros3"), "--protocol"),
        (("replay", "{log}", "--port", "0", "--speed", "nan"), "speed"),
        (("replay", "{log}", "--port", "0", "--loops", "-1"), "loops"),
        (("replay", "{log}", "--port", "0", "--topic", "/nope"), "/nope"),
        (("replay", "{tmp}/garbage.mcap", "--port", "0"), "garbage.mcap"),
        (("unity", "-o", "{tmp}/u.mcap", "--duration", "inf"), "--duration"),
        (("unity", "-o", "{tmp}/u.mcap", "--port", "-1"), "--port"),
        (("unity", "-o", "{tmp}/u.mcap", "--unity-map", "ned"), "Unity map"),
        (
            ("unity", "-o", "/proc/uwval-no-such-dir/u.mcap", "--duration", "0.1"),
            "/proc/uwval-no-such-dir/u.mcap",
        ),
        (("scan", "{tmp}/none.mcap"), "none.mcap"),
    ],
)
def test_bridge_cli_bad_input_is_one_clean_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], args: tuple[str, ...], needle: str
) -> None:
    from uwval.cli import main

    log = tmp_path / "gz.mcap"
    rec = BridgeRecorder(open_mcap_writer(log))
    rec.gazebo_pose("model_rov_pose", 0, np.zeros(3), np.array([0.0, 0.0, 0.0, 1.0]))
    rec.close()
    (tmp_path / "garbage.mcap").write_bytes(b"not an mcap at all")
    argv = [a.replace("{log}", str(log)).replace("{tmp}", str(tmp_path)) for a in args]
    with pytest.raises(SystemExit) as stop:
        main(["bridge", *argv])
    captured = capsys.readouterr()
    assert stop.value.code == 2, captured
    lines = [ln for ln in captured.err.splitlines() if ln.strip()]
    # one line: nothing was served or printed before the error
    assert len(lines) == 1 and lines[0].startswith("error:"), captured.err
    assert needle in lines[0]
