"""run_session: ticks -> real loopback TCP -> Unity-like client -> MCAP, on a virtual clock."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from uwval.bridge.errors import BridgeError
from uwval.bridge.gazebo import ticks_from_streams
from uwval.bridge.recorder import open_mcap_writer
from uwval.bridge.session import SessionStats, run_session
from uwval.frames import convert_arrays, enu_from_unity
from uwval.io import list_topics, read_stream
from uwval.posestream import PoseStream
from uwval.rotations import quat_from_rpy

PERIOD_NS = 20_000_000  # 50 Hz publish ticks


def motion(n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Synthetic vehicle motion: stamps (ns), ENU positions, FLU->ENU quaternions."""
    t = np.arange(n, dtype=np.int64) * PERIOD_NS + 1_000_000_000
    s = (t - t[0]) * 1e-9
    pos = np.stack([0.5 * s, np.sin(s), -0.1 * s], axis=1)
    rpy = np.stack([0.2 * np.sin(2 * s), 0.1 * np.cos(s), 0.7 * s], axis=1)
    return t, pos, quat_from_rpy(rpy)


def ticks(n: int = 200) -> Iterator[tuple[int, dict[str, tuple[np.ndarray, np.ndarray]]]]:
    t, pos, quat = motion(n)
    for k in range(n):
        yield (
            int(t[k]),
            {
                "model_rov_pose": (pos[k], quat[k]),
                "gui_camera_pose": (pos[k] + [-3.0, 0.0, 1.0], quat[k]),
            },
        )


def session(
    tmp_path: Path, name: str = "run.mcap", n: int = 200, **kw: Any
) -> tuple[Path, SessionStats]:
    path = tmp_path / name
    writer = open_mcap_writer(path)
    try:
        stats = run_session(ticks(n), writer, **kw)
    finally:
        writer.close()
    return path, stats


def same_rotation(a: np.ndarray, b: np.ndarray, atol: float = 1e-12) -> bool:
    dots = np.abs(np.sum(a * b, axis=1))
    return bool(np.all(np.abs(dots - 1.0) < atol))


@pytest.mark.parametrize(
    ("unity_map", "protocol"), [("unity-flu", "ROS2"), ("unity-enu", "ROS2"), ("unity-flu", "ROS1")]
)
def test_unity_stream_back_in_enu_equals_gazebo_at_applied_stamps(
    tmp_path: Path, unity_map: str, protocol: str
) -> None:
    path, stats = session(
        tmp_path,
        unity_map=unity_map,
        protocol=protocol,
        latency_s=0.03,
        jitter_s=0.002,
        drop_prob=0.1,
        unity_clock_offset_s=2.5,
        seed=3,
    )
    topics = {t.name: t for t in list_topics(path)}
    assert set(topics) == {
        "/gazebo/model_rov_pose",
        "/gazebo/gui_camera_pose",
        "/unity/model_rov_pose",
        "/unity/gui_camera_pose",
        "/unity/model_rov_pose/applied_stamp",
        "/unity/gui_camera_pose/applied_stamp",
    }
    for name in ("model_rov_pose", "gui_camera_pose"):
        gz = read_stream(path, f"/gazebo/{name}")
        un = read_stream(path, f"/unity/{name}")
        assert gz.frame == "enu"
        assert un.frame == unity_map
        assert len(gz) == 200
        assert un.applied_stamp is not None
        back = enu_from_unity(un)
        idx = np.searchsorted(gz.t, un.applied_stamp)
        assert np.array_equal(gz.t[idx], un.applied_stamp)  # every applied stamp was sent
        np.testing.assert_allclose(back.position, gz.position[idx], atol=1e-12, rtol=0)
        assert same_rotation(back.orientation, gz.orientation[idx])
        # Unity's header stamps are its own clock: frame time + 2.5 s offset.
        assert np.all(un.t - 2_500_000_000 >= un.applied_stamp + 30_000_000)
    assert stats.sent == 400
    assert stats.received == 400
    assert stats.delivered + stats.dropped == stats.received


def test_unity_poses_really_are_in_unity_axes(tmp_path: Path) -> None:
    path, _ = session(tmp_path, n=20, unity_map="unity-flu")
    gz = read_stream(path, "/gazebo/model_rov_pose")
    un = read_stream(path, "/unity/model_rov_pose")
    assert un.applied_stamp is not None
    g = gz.position[np.searchsorted(gz.t, un.applied_stamp)]
    # ROS-TCP-Connector FLU: ROS x -> Unity z, ROS y -> Unity -x, ROS z -> Unity y.
    np.testing.assert_allclose(un.position, np.stack([-g[:, 1], g[:, 2], g[:, 0]], axis=1))


def test_applied_pose_is_the_latest_arrived_one(tmp_path: Path) -> None:
    latency = 0.045
    path, stats = session(tmp_path, latency_s=latency, frame_rate=60.0)
    gz = read_stream(path, "/gazebo/model_rov_pose")
    un = read_stream(path, "/unity/model_rov_pose")
    assert un.applied_stamp is not None
    frame_t = un.t  # no clock offset: Unity clock = virtual frame time
    # Latest Gazebo stamp that had arrived (stamp + latency <= frame time).
    expect = gz.t[np.searchsorted(gz.t + int(latency * 1e9), frame_t, side="right") - 1]
    np.testing.assert_array_equal(un.applied_stamp, expect)
    assert stats.latency_mean_s == pytest.approx(latency)
    assert stats.render_lag_mean_s >= latency
    # Unity keeps rendering until the last pose arrived, and shows it.
    assert un.applied_stamp[-1] == gz.t[-1]
    # 60 Hz frames over the 3.98 s of ticks + 45 ms latency.
    assert stats.frames == pytest.approx((3.98 + latency) * 60, abs=2)
    assert stats.applied == len(un) + len(read_stream(path, "/unity/gui_camera_pose"))


def test_same_seed_same_log_other_seed_other_drops(tmp_path: Path) -> None:
    kw: dict[str, Any] = {"drop_prob": 0.3, "jitter_s": 0.003, "latency_jitter_s": 0.01}
    a, sa = session(tmp_path, "a.mcap", seed=1, **kw)
    b, sb = session(tmp_path, "b.mcap", seed=1, **kw)
    c, sc = session(tmp_path, "c.mcap", seed=2, **kw)
    ua, ub, uc = (read_stream(p, "/unity/model_rov_pose") for p in (a, b, c))
    assert np.array_equal(ua.t, ub.t)
    assert ua.applied_stamp is not None
    assert ub.applied_stamp is not None
    assert np.array_equal(ua.applied_stamp, ub.applied_stamp)
    assert np.array_equal(ua.position, ub.position)
    assert sa.dropped == sb.dropped
    assert not np.array_equal(ua.t, uc.t)
    # 400 messages at p = 0.3: the drop count is binomial (mean 120, sd ~9.2).
    for s in (sa, sc):
        assert 80 < s.dropped < 160


def test_disconnect_loses_messages_then_reconnects_and_resubscribes(tmp_path: Path) -> None:
    path, stats = session(tmp_path, n=250, disconnects=[1.5], reconnect_delay_s=1.0, latency_s=0.05)
    assert stats.disconnects == 1
    assert stats.reconnects == 1
    # Lost: 2 topics x (50 ticks sent during the 1 s outage + the 2 ticks in flight at the
    # drop: sent at 1.46 s and 1.48 s, they would arrive after 1.5 s with 50 ms latency).
    assert stats.lost_disconnected == 2 * (50 + 2)
    assert stats.delivered + stats.dropped + stats.lost_disconnected == stats.sent
    assert stats.received == stats.sent - 2 * 50  # in-flight ones were read, then discarded
    un = read_stream(path, "/unity/model_rov_pose")
    assert un.applied_stamp is not None
    t0 = 1_000_000_000
    down = (un.t >= t0 + 1_500_000_000) & (un.t < t0 + 2_500_000_000)
    # While disconnected Unity keeps showing the last pose received before the drop.
    assert down.any()
    assert len(np.unique(un.applied_stamp[down])) == 1
    assert un.applied_stamp[down][0] <= t0 + 1_500_000_000
    # After the reconnect (and re-registration) fresh poses flow again.
    after = un.t >= t0 + 2_600_000_000
    assert un.applied_stamp[after].max() > t0 + 2_600_000_000


def test_realtime_paces_to_the_wall_clock(tmp_path: Path) -> None:
    _, stats = session(tmp_path, n=25, realtime=True)  # 0.48 s of sim time
    assert stats.wall_time_s >= 0.45
    assert stats.received == 50


def test_bad_arguments_raise_bridge_errors(tmp_path: Path) -> None:
    with pytest.raises(BridgeError, match="no ticks"):
        run_session(iter(()), open_mcap_writer(tmp_path / "x.mcap"))
    with pytest.raises(BridgeError, match="drop probability"):
        session(tmp_path, "y.mcap", drop_prob=1.5)
    with pytest.raises(BridgeError, match="not a Unity map"):
        session(tmp_path, "z.mcap", unity_map="ned")


def test_ticks_from_streams_merges_and_converts() -> None:
    t, pos, quat = motion(10)
    veh = PoseStream.from_arrays(t, pos, quat)
    pos_u, quat_u = convert_arrays(pos[::2], quat[::2], "enu", "unity-flu")
    cam = PoseStream.from_arrays(t[::2], pos_u, quat_u, frame="unity-flu")
    out = list(ticks_from_streams(veh, cam))
    assert [k[0] for k in out] == t.tolist()
    assert [sorted(k[1]) for k in out[:2]] == [
        ["gui_camera_pose", "model_rov_pose"],
        ["model_rov_pose"],
    ]
    np.testing.assert_allclose(out[2][1]["gui_camera_pose"][0], pos[2], atol=1e-12)
    with pytest.raises(BridgeError, match="1 names for 2 streams"):
        list(ticks_from_streams(veh, cam, names=["a"]))


def test_live_peer_on_the_session_endpoint_gets_the_poses_too(tmp_path: Path) -> None:
    import socket
    import threading
    import time

    from uwval.bridge import protocol as wire
    from uwval.bridge.unity_client import UnityConnection

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    got: list[int] = []

    def live_unity() -> None:
        conn = UnityConnection(
            "127.0.0.1", port, subscriptions={"model_rov_pose": wire.POSE_STAMPED}
        )
        deadline = time.monotonic() + 20
        while time.monotonic() < deadline:
            try:
                conn.connect(timeout=1.0)
                break
            except BridgeError:
                time.sleep(0.02)
        while conn.connected and len(got) < 60:
            try:
                frames = conn.poll(2.0)
            except BridgeError:
                break
            got.extend(wire.decode_pose_stamped(f.payload)[0] for f in frames)
        conn.close()

    peer = threading.Thread(target=live_unity)
    peer.start()
    _, stats = session(tmp_path, n=75, realtime=True, port=port)  # 1.5 s, paced
    peer.join(30)
    assert stats.received == 150  # our own Unity-like client missed nothing
    assert len(got) >= 30  # the live peer joined within the run and got poses
    t, _, _ = motion(75)
    assert set(got) <= set(t.tolist())
    assert got == sorted(got)


@pytest.mark.parametrize("fmt", ["mcap", "rosbag2", "rosbag1"])
def test_recorded_bytes_equal_the_writers_own_rosbags_encoding(tmp_path: Path, fmt: str) -> None:
    """The writers' write_pose/write_header (numpy encoding) record the same bytes as writing
    rosbags' serialization of each message."""
    from uwval.io import open_writer
    from uwval.io.ros import HEADER, POSE_STAMPED, header_msg, pose_stamped, typestore

    ros = 1 if fmt == "rosbag1" else 2
    ts = typestore(ros)
    ser = ts.serialize_ros1 if ros == 1 else ts.serialize_cdr
    t, pos, quat = motion(50)
    logs = {}
    for how in ("rosbags", "numpy"):
        path = tmp_path / f"{how}{'.bag' if fmt == 'rosbag1' else '.mcap' if fmt == 'mcap' else ''}"
        with open_writer(path, fmt) as w:
            for k in range(len(t)):
                tk = int(t[k])
                if how == "numpy":
                    w.write_pose("/p", tk, pos[k], quat[k], "unity-flu", tk + 5)
                    w.write_header("/h", tk - 7, tk + 5, "world")
                    continue
                msg = pose_stamped(tk, pos[k], quat[k], "unity-flu", ros)
                w.write_raw("/p", POSE_STAMPED, bytes(ser(msg, POSE_STAMPED)), tk + 5)
                w.write_raw(
                    "/h", HEADER, bytes(ser(header_msg(tk - 7, "world", ros), HEADER)), tk + 5
                )
        logs[how] = path
    a, b = (_payloads(logs[h]) for h in ("rosbags", "numpy"))
    assert a == b
    assert len(a["/p"]) == len(a["/h"]) == 50


def _payloads(path: Path) -> dict[str, list[tuple[int, bytes]]]:
    """(log time, raw bytes) per topic, read by the mcap library or rosbags' AnyReader."""
    out: dict[str, list[tuple[int, bytes]]] = {}
    if path.suffix == ".mcap":
        from mcap.reader import make_reader

        with open(path, "rb") as fh:
            for _, ch, m in make_reader(fh).iter_messages():
                out.setdefault(ch.topic, []).append((m.log_time, bytes(m.data)))
        return out
    from rosbags.highlevel import AnyReader

    with AnyReader([path]) as reader:
        for conn, t, raw in reader.messages():
            out.setdefault(conn.topic, []).append((t, bytes(raw)))
    return out


def test_session_options_are_checked_once_and_overridable(tmp_path: Path) -> None:
    from uwval.bridge.session import BridgeSession, SessionOptions
    from uwval.errors import ConfigError

    with pytest.raises(ConfigError, match="--format"):
        SessionOptions(log_format="zip")
    with pytest.raises(BridgeError):
        SessionOptions(unity_map="ned")
    with pytest.raises(TypeError, match="unknown option"):
        run_session(ticks(5), open_mcap_writer(tmp_path / "x.mcap"), frame_rat=30.0)
    opts = SessionOptions(latency_s=0.02, drop_prob=0.1, disconnects=[1.0])
    assert opts.disconnects == (1.0,)
    w1, w2 = open_mcap_writer(tmp_path / "a.mcap"), open_mcap_writer(tmp_path / "b.mcap")
    try:
        s1 = BridgeSession(w1, opts, seed=3).run(ticks(200))
        s2 = run_session(ticks(200), w2, seed=3, latency_s=0.02, drop_prob=0.1, disconnects=[1.0])
    finally:
        w1.close()
        w2.close()
    d1, d2 = s1.as_dict(), s2.as_dict()
    d1.pop("wall_time_s")
    d2.pop("wall_time_s")
    assert d1 == d2 and s1.dropped > 0 and s1.disconnects == 1


def test_pose_encoder_is_byte_identical_to_the_wire_encoder() -> None:
    from uwval.bridge import protocol as wire
    from uwval.bridge.gazebo import PoseEncoder

    rng = np.random.default_rng(0)
    for proto in ("ROS2", "ROS1"):
        for fid in ("", "w", "world", "unity-flu", "abcdefgh", "abcdefghi"):
            enc = PoseEncoder(fid, proto)  # type: ignore[arg-type]
            for _ in range(50):
                t = int(rng.integers(0, 2**40))
                p, q = rng.normal(size=3), rng.normal(size=4)
                seq = int(rng.integers(0, 2**33))
                want = wire.encode_pose_stamped(t, p, q, fid, proto, seq=seq)  # type: ignore[arg-type]
                assert enc.encode(t, p, q, seq) == want
                assert enc.encode(t, list(p), tuple(q), seq) == want


@pytest.mark.parametrize("lookahead", [0.05, 3.0])
def test_lookahead_changes_nothing_recorded(tmp_path: Path, lookahead: float) -> None:
    """Virtual arrivals depend on stamps and the seeded faults only: how far ahead ticks are
    sent (socket batching) leaves the log and the statistics as they are."""
    kw: dict[str, Any] = dict(
        latency_s=0.03, latency_jitter_s=0.02, drop_prob=0.1, jitter_s=0.003, disconnects=[1.3]
    )
    a, sa = session(tmp_path, "a.mcap", 300, lookahead_s=1.0, seed=4, **kw)
    b, sb = session(tmp_path, "b.mcap", 300, lookahead_s=lookahead, seed=4, **kw)
    da, db = sa.as_dict(), sb.as_dict()
    da.pop("wall_time_s")
    db.pop("wall_time_s")
    assert da == db and sa.dropped > 0
    for topic in ("/gazebo/model_rov_pose", "/unity/model_rov_pose"):
        x, y = read_stream(a, topic), read_stream(b, topic)
        assert np.array_equal(x.t, y.t) and np.array_equal(x.position, y.position)


def test_options_module_stays_light_and_agrees_with_the_wire() -> None:
    """The CLI imports the options at start-up: no numpy, no sockets; its defaults are the
    bridge's."""
    import subprocess
    import sys

    from uwval.bridge import protocol as wire
    from uwval.bridge.options import DEFAULT_HOST

    assert DEFAULT_HOST == wire.DEFAULT_HOST
    code = (
        "import sys, uwval.bridge.options; print('numpy' in sys.modules, 'socket' in sys.modules)"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["False", "False"]


def test_a_run_longer_than_the_endpoint_idle_timeout_keeps_its_link(tmp_path: Path) -> None:
    # The Unity-like client only receives; without the Connector's 1 s keepalive the
    # endpoint closed it after 5 s of wall time (its idle timeout), so a long simulate on a
    # busy machine failed with "endpoint ... closed the connection". 6 s paced to the clock.
    _, stats = session(tmp_path, n=300, realtime=True)
    assert stats.wall_time_s >= 5.9
    assert stats.received == 600
