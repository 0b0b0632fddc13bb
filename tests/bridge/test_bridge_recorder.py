"""The recorder: topic layout, nothing lost on a clean stop, readable after SIGKILL."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np

from uwval.bridge.recorder import BridgeRecorder, open_mcap_writer, scan_mcap
from uwval.io import list_topics, read_stream
from uwval.io.ros import typestore

REPO = Path(__file__).resolve().parents[2]


def test_clean_close_keeps_every_message_with_the_right_frames(tmp_path: Path) -> None:
    path = tmp_path / "rec.mcap"
    rec = BridgeRecorder(open_mcap_writer(path), unity_map="unity-enu", flush_every=7)
    q = np.array([0.0, 0.0, 0.0, 1.0])
    for k in range(50):
        rec.gazebo_pose("model_rov_pose", k * 10_000_000, np.array([k, 0.0, 0.0]), q)
        rec.unity_pose(
            "model_rov_pose",
            5_000_000_000 + k * 16_000_000,
            np.array([0.0, 0.0, k]),
            q,
            applied_stamp_ns=k * 10_000_000,
        )
    rec.close()
    rec.close()  # idempotent
    counts = {t.name: t.count for t in list_topics(path)}
    assert counts == {
        "/gazebo/model_rov_pose": 50,
        "/unity/model_rov_pose": 50,
        "/unity/model_rov_pose/applied_stamp": 50,
    }
    assert rec.flushed == rec.written
    report = scan_mcap(path)
    assert report.complete
    assert report.lost_bytes == 0
    un = read_stream(path, "/unity/model_rov_pose")
    assert un.frame == "unity-enu"
    assert un.applied_stamp is not None
    np.testing.assert_array_equal(un.applied_stamp, np.arange(50) * 10_000_000)
    gz = read_stream(path, "/gazebo/model_rov_pose")
    assert gz.frame == "enu"
    from mcap.reader import make_reader

    with open(path, "rb") as fh:
        frame_ids = {
            ch.topic: typestore(2).deserialize_cdr(m.data, s.name).header.frame_id
            for s, ch, m in make_reader(fh).iter_messages()
            if s is not None and s.name.endswith("PoseStamped")
        }
    assert frame_ids == {"/gazebo/model_rov_pose": "world", "/unity/model_rov_pose": "unity-enu"}


CHILD = textwrap.dedent("""
    import sys, time
    import numpy as np
    from uwval.bridge.recorder import BridgeRecorder, open_mcap_writer
    rec = BridgeRecorder(open_mcap_writer(sys.argv[1]), flush_every=100,
                         flush_interval_s=1e9)
    q = np.array([0.0, 0.0, 0.0, 1.0])
    k = 0
    while True:
        rec.gazebo_pose("model_rov_pose", k * 20_000_000, np.array([k, 0.0, 0.0]), q)
        k += 1
        if k % 100 == 0:
            print("flushed", rec.flushed.get("/gazebo/model_rov_pose", 0), flush=True)
        if k % 10 == 0:
            time.sleep(0.001)
""")


def test_sigkill_leaves_everything_up_to_the_last_flush_readable(tmp_path: Path) -> None:
    path = tmp_path / "killed.mcap"
    env = dict(os.environ, PYTHONPATH=str(REPO))
    proc = subprocess.Popen(
        [sys.executable, "-c", CHILD, str(path)], stdout=subprocess.PIPE, text=True, env=env
    )
    assert proc.stdout is not None
    flushed = 0
    deadline = time.monotonic() + 60
    while flushed < 700 and time.monotonic() < deadline:
        line = proc.stdout.readline()
        if not line:
            break
        flushed = int(line.split()[1])
    time.sleep(0.05)  # let it write a partial chunk past the flush
    proc.send_signal(signal.SIGKILL)
    proc.wait(10)
    assert proc.returncode == -signal.SIGKILL
    assert flushed >= 700
    report = scan_mcap(path)
    assert not report.complete
    got = report.messages.get("/gazebo/model_rov_pose", 0)
    assert got >= flushed, report.describe()
    assert "truncated" in report.describe()
    # What survived is the first `got` messages, intact and in order.
    from mcap.records import Message
    from mcap.stream_reader import StreamReader

    xs = []
    with open(path, "rb") as fh:
        try:
            for r in StreamReader(fh).records:
                if isinstance(r, Message):
                    xs.append(
                        typestore(2)
                        .deserialize_cdr(r.data, "geometry_msgs/msg/PoseStamped")
                        .pose.position.x
                    )
        except Exception:
            pass  # the truncated tail
    assert xs == [float(k) for k in range(got)]


def test_scan_cli_reports_complete_and_truncated_logs(tmp_path: Path) -> None:
    from typer.testing import CliRunner

    from uwval.cli import _register, app

    _register()
    path = tmp_path / "ok.mcap"
    rec = BridgeRecorder(open_mcap_writer(path))
    for k in range(30):
        rec.gazebo_pose("model_rov_pose", k, np.zeros(3), np.array([0.0, 0.0, 0.0, 1.0]))
    rec.close()
    res = CliRunner().invoke(app, ["bridge", "scan", str(path)])
    assert res.exit_code == 0
    assert "complete, 30 messages" in res.output
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(path.read_bytes()[:-200])  # lose the summary and footer
    res = CliRunner().invoke(app, ["bridge", "scan", str(cut)])
    assert res.exit_code == 1
    assert "truncated" in res.output
    assert "/gazebo/model_rov_pose: 30" in res.output


def test_scan_of_a_damaged_index_is_not_complete(tmp_path: Path) -> None:
    """Issue 14: `bridge scan` called a file with a zeroed MessageIndex complete."""
    import struct

    path = tmp_path / "run.mcap"
    rec = BridgeRecorder(open_mcap_writer(path), unity_map="unity-flu", flush_every=50)
    q = np.array([0.0, 0.0, 0.0, 1.0])
    for k in range(600):
        rec.gazebo_pose("model_rov_pose", k * 10_000_000, np.array([k * 0.01, 0.0, 0.0]), q)
        rec.unity_pose("model_rov_pose", k * 10_000_000 + 1, np.zeros(3), q, k * 10_000_000)
    rec.close()
    assert scan_mcap(path).complete
    data = bytearray(path.read_bytes())
    pos = 8
    while True:  # find a MessageIndex record with entries
        op, ln = struct.unpack_from("<BQ", data, pos)
        if op == 7 and ln > 80:
            break
        pos += 9 + ln
    data[pos + 15 : pos + 15 + 64] = bytes(64)
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(bytes(data))
    report = scan_mcap(bad)
    assert not report.complete
    assert "MessageIndex disagrees" in report.error
    assert report.messages == scan_mcap(path).messages  # read by walking: nothing lost
