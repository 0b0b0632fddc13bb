"""Decode speed: 1M PoseStamped in one MCAP (ROS 2 CDR) and in one ROS 1 bag, read by uwval
vs rosbags (both) and mcap_ros2 (MCAP).

The file is generated deterministically (seeded) with uwval's bulk writer, once per run, in a
temporary directory. Each reader produces the same arrays (t, position, orientation); the
row reports messages per second (median of alternating repetitions).
"""

from __future__ import annotations

import tempfile
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.common import BenchRow, alternate, median
from uwval.posestream import PoseStream

TOPIC = "/gazebo/model_rov_pose"


def make_log(path: Path, n: int, seed: int = 7, fmt: str = "mcap") -> PoseStream:
    """Write ``n`` PoseStamped (1 kHz stamps, random walk poses) to ``path`` (``fmt``)."""
    from uwval.io import open_writer, write_stream

    rng = np.random.default_rng(seed)
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1)[:, None]
    s = PoseStream.from_arrays(
        np.arange(n, dtype=np.int64) * 1_000_000 + 10**18,
        np.cumsum(rng.normal(size=(n, 3)) * 1e-3, axis=0),
        q,
    )
    with open_writer(path, fmt) as w:
        write_stream(w, TOPIC, s, "world")
    return s


def read_uwval(path: Path) -> int:
    from uwval.io import read_stream

    return len(read_stream(path, TOPIC))


def read_rosbags(path: Path) -> int:
    """rosbags' AnyReader + deserialize_cdr per message, into the same arrays."""
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    rows = []
    with AnyReader([path], default_typestore=store) as reader:
        conns = [c for c in reader.connections if c.topic == TOPIC]
        for conn, _t, raw in reader.messages(connections=conns):
            m: Any = (
                reader.deserialize(raw, conn.msgtype)
                if path.suffix == ".bag"
                else store.deserialize_cdr(raw, conn.msgtype)
            )
            p, o = m.pose.position, m.pose.orientation
            rows.append(
                (
                    m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec,
                    p.x,
                    p.y,
                    p.z,
                    o.x,
                    o.y,
                    o.z,
                    o.w,
                )
            )
    return len(np.asarray(rows))


def read_mcap_ros2(path: Path) -> int:
    """mcap + mcap_ros2's DecoderFactory (iter_decoded_messages), into the same arrays."""
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    rows = []
    with open(path, "rb") as fh:
        reader = make_reader(fh, decoder_factories=[DecoderFactory()])
        for _s, _c, _m, msg in reader.iter_decoded_messages(topics=[TOPIC]):
            p, o = msg.pose.position, msg.pose.orientation
            rows.append(
                (
                    msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec,
                    p.x,
                    p.y,
                    p.z,
                    o.x,
                    o.y,
                    o.z,
                    o.w,
                )
            )
    return len(np.asarray(rows))


def run(quick: bool = False) -> list[BenchRow]:
    n = 100_000 if quick else 1_000_000
    n_peer = 20_000 if quick else 100_000  # peers are 10-50x slower: a smaller file, same rate
    with tempfile.TemporaryDirectory(prefix="uwval-bench-decode-") as tmp:
        big = Path(tmp) / "poses.mcap"
        small = Path(tmp) / "poses_small.mcap"
        make_log(big, n)
        make_log(small, n_peer)
        reps = 3 if quick else 5
        (t_uw,) = alternate([lambda: read_uwval(big)], reps)
        t_rb, t_mc = alternate([lambda: read_rosbags(small), lambda: read_mcap_ros2(small)], 2)
        # ROS 1 serialization: the same poses in a .bag, rosbags' rosbag1 reader as the peer
        big1, small1 = Path(tmp) / "poses.bag", Path(tmp) / "poses_small.bag"
        make_log(big1, n, fmt="rosbag1")
        make_log(small1, n_peer, fmt="rosbag1")
        (t_uw1,) = alternate([lambda: read_uwval(big1)], reps)
        (t_rb1,) = alternate([lambda: read_rosbags(small1)], 2)
    uw1 = n / median(t_uw1)
    rb1 = n_peer / median(t_rb1)
    uw = n / median(t_uw)
    rb = n_peer / median(t_rb)
    mc = n_peer / median(t_mc)
    note = f"uwval on {n} msgs, peers on {n_peer} msgs (rate is per message)"
    return [
        BenchRow(
            "decode PoseStamped MCAP vs rosbags",
            uw,
            "msg/s",
            rb,
            "rosbags",
            ">= 1.2M msg/s",
            uw >= 1.2e6,
            note,
        ),
        BenchRow(
            "decode PoseStamped MCAP vs mcap_ros2",
            uw,
            "msg/s",
            mc,
            "mcap_ros2",
            ">= 1.2M msg/s",
            uw >= 1.2e6,
            note,
        ),
        BenchRow(
            "decode PoseStamped ROS 1 bag vs rosbags",
            uw1,
            "msg/s",
            rb1,
            "rosbags",
            ">= 1.2M msg/s",
            uw1 >= 1.2e6,
            note,
        ),
    ]


if __name__ == "__main__":
    import sys

    for row in run(quick="--quick" in sys.argv):
        print(
            f"{row.name}: uwval {row.uwval:,.0f} {row.unit}, {row.peer_name} "
            f"{row.peer:,.0f} {row.unit}, ratio {row.ratio:.1f}x, target {row.target} "
            f"met={row.met} ({row.notes})"
        )
