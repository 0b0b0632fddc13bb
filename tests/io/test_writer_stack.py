"""One writer stack (issue 30): the logs uwval writes are byte-identical to the logs of the
code before the bridge's block writers were folded into uwval/io (hashes taken from logs
written by that code, commit 65b6cf0, from the same seeded input), and read back whole by the
field's own libraries (mcap's reader and ros2 decoder, rosbags' AnyReader)."""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np
import pytest

from uwval.bridge.recorder import BridgeRecorder
from uwval.io.writers import open_writer, write_stream
from uwval.posestream import PoseStream

N = 3000
#: sha256 of each log as the code before the fold wrote it (zstd 1.5.7 for the MCAP chunks,
#: rosbags 0.11.9's ROS 1 records).
BEFORE = {
    ("rec", "mcap"): "4e5b290ce095d7931c43db406508d589008aeeed5c26cda4d32e21bd1eed4fcf",
    ("rec", "rosbag1"): "9856484a9ce301521f28781caefe6d7c24c7176e5aa46baec19a3ec8aa1f814a",
    ("direct", "mcap"): "4368024df531c9c63fec92dc03fe3174c856e8eae056536a854cc4259dd192cd",
    ("direct", "rosbag1"): "d294405738293dd3e002aa85afd8c51e06581829babbefc629667dd1a4bfab7b",
}
SUFFIX = {"mcap": ".mcap", "rosbag1": ".bag"}


def _input() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(5)
    t = 1_000_000_000 + np.cumsum(rng.integers(1, 30_000_000, N))
    pos = rng.normal(size=(N, 3)) * 100
    q = rng.normal(size=(N, 4))
    return t, pos, q / np.linalg.norm(q, axis=1)[:, None]


def _recorded(path: Path, fmt: str) -> None:
    """A bridged run's recording: two Gazebo topics (two frame ids), Unity poses with their
    applied stamps, flushed every 700 messages."""
    t, pos, q = _input()
    w = open_writer(path, fmt, metadata={"run": "ref", "x": "1"})
    rec = BridgeRecorder(w, unity_map="unity-flu", flush_every=700, flush_interval_s=1e9)
    for i in range(N):
        rec.gazebo_pose("model_rov_pose", int(t[i]), pos[i], q[i])
        if i % 3 == 0:
            rec.gazebo_pose("gui_camera_pose", int(t[i]), pos[i] * 2, q[i], frame_id="cam")
        if i % 2 == 1:
            rec.unity_pose("model_rov_pose", int(t[i]) + 5_000_000, pos[i], q[i], int(t[i - 1]))
    rec.close()


def _direct(path: Path, fmt: str) -> None:
    """One-by-one writes, a flush, then a whole stream."""
    t, pos, q = _input()
    with open_writer(path, fmt, metadata={"run": "direct"}) as w:
        for i in range(200):
            w.write_pose("/a/pose", int(t[i]), pos[i], q[i], "world", int(t[i]) + 7)
            w.write_header("/a/pose/applied_stamp", int(t[i]) - 3, int(t[i]) + 7, "world")
        w.flush()
        s = PoseStream(t=t[:500], position=pos[:500], orientation=q[:500], frame="enu", topic="/s")
        write_stream(w, "/b/pose", s, "world")


@pytest.mark.parametrize("fmt", ["mcap", "rosbag1"])
@pytest.mark.parametrize("how", ["rec", "direct"])
def test_logs_are_byte_identical_to_before_the_fold(tmp_path: Path, how: str, fmt: str) -> None:
    import zstandard

    if fmt == "mcap" and zstandard.ZSTD_VERSION != (1, 5, 7):
        pytest.skip(f"the MCAP hashes were taken with zstd 1.5.7, this is {zstandard.ZSTD_VERSION}")
    path = tmp_path / f"{how}{SUFFIX[fmt]}"
    (_recorded if how == "rec" else _direct)(path, fmt)
    assert hashlib.sha256(path.read_bytes()).hexdigest() == BEFORE[(how, fmt)]


def test_every_message_and_the_metadata_read_back(tmp_path: Path) -> None:
    """What the field's readers decode from each format equals what was written."""
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory
    from rosbags.highlevel import AnyReader

    t, pos, _ = _input()
    for fmt, suffix in (("mcap", ".mcap"), ("rosbag1", ".bag"), ("rosbag2", "")):
        path = tmp_path / f"rec_{fmt}{suffix}"
        _recorded(path, fmt)
        if fmt == "mcap":
            with path.open("rb") as f:
                reader = make_reader(f, decoder_factories=[DecoderFactory()])
                meta = {m.name: dict(m.metadata) for m in reader.iter_metadata()}
                msgs = [(c.topic, d) for _, c, _, d in reader.iter_decoded_messages()]
            assert meta["uwval"] == {"run": "ref", "x": "1"}
        else:
            with AnyReader([path]) as reader:
                msgs = [
                    (c.topic, reader.deserialize(raw, c.msgtype)) for c, _, raw in reader.messages()
                ]
        gz = [m for topic, m in msgs if topic == "/gazebo/model_rov_pose"]
        assert len(gz) == N
        got = np.array([[m.pose.position.x, m.pose.position.y, m.pose.position.z] for m in gz])
        np.testing.assert_array_equal(got, pos)
        stamps = [m.header.stamp.sec * 10**9 + m.header.stamp.nanosec for m in gz]
        assert stamps == t.tolist()
        applied = [m for topic, m in msgs if topic == "/unity/model_rov_pose/applied_stamp"]
        assert len(applied) == N // 2
