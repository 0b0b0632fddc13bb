"""The bridge at its edges: a recording cut mid-file (crash scan byte counts), a run where
nothing was delivered, a Unity-like recorder that never connects, generic bodies via rosbags."""

from __future__ import annotations

import json
import socket
from pathlib import Path

import numpy as np
from cli_runner import run_uwval as _uwval

from uwval.bridge.recorder import BridgeRecorder, open_mcap_writer, scan_mcap


def test_scan_counts_the_bytes_really_lost_after_a_cut(tmp_path: Path) -> None:
    path = tmp_path / "rec.mcap"
    rec = BridgeRecorder(open_mcap_writer(path), unity_map="unity-flu", flush_every=100)
    q = np.array([0.0, 0.0, 0.0, 1.0])
    for k in range(3000):
        rec.gazebo_pose("model_rov_pose", k * 20_000_000, np.array([k * 0.01, 0.0, 0.0]), q)
    rec.close()
    full = path.read_bytes()
    from mcap.reader import make_reader

    with open(path, "rb") as fh:
        summary = make_reader(fh).get_summary()
    assert summary is not None
    chunks = sorted(summary.chunk_indexes, key=lambda c: c.chunk_start_offset)
    assert len(chunks) >= 3
    end2 = chunks[1].chunk_start_offset + chunks[1].chunk_length
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(full[: end2 + 50])  # 50 bytes into whatever follows the 2nd chunk
    report = scan_mcap(cut)
    assert not report.complete
    assert report.lost_bytes <= 50 + 4096  # at most the partial record after the chunk
    assert report.valid_bytes >= end2 - 4096


def test_nothing_delivered_means_no_latency_figures(tmp_path: Path) -> None:
    res = _uwval(
        "simulate", "--duration", "1", "--drop", "1", "--json", "-o", str(tmp_path / "d.mcap")
    )
    assert res.returncode == 0, res.stderr
    bridge = json.loads(res.stdout)["bridge"]
    assert bridge["delivered"] == 0
    assert bridge["latency_mean_s"] is None
    assert bridge["render_lag_mean_s"] is None


def test_unity_recorder_that_never_connects_fails(tmp_path: Path) -> None:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]  # nothing listens here once closed
    res = _uwval(
        "bridge", "unity", "--port", str(port), "--duration", "1.5", "-o", str(tmp_path / "u.mcap")
    )
    assert res.returncode == 2, res.stdout + res.stderr
    assert "never connected" in res.stderr
    assert "Traceback" not in res.stderr


def test_generic_bodies_round_trip_through_rosbags_in_both_protocols() -> None:
    from uwval.bridge import protocol as wire
    from uwval.io.ros import header_msg

    for proto, ver in (("ROS2", 2), ("ROS1", 1)):
        msg = header_msg(1_700_000_000_123_456_789, "world", ros_version=ver)
        body = wire.encode_with_rosbags(msg, "std_msgs/Header", proto)  # type: ignore[arg-type]
        if proto == "ROS2":
            assert body[:4] == b"\x00\x01\x00\x00"  # CDR little-endian encapsulation header
        back = wire.decode_with_rosbags(body, "std_msgs/Header", proto)  # type: ignore[arg-type]
        assert back.frame_id == "world"
        assert back.stamp.sec == 1_700_000_000
        assert back.stamp.nanosec == 123_456_789
