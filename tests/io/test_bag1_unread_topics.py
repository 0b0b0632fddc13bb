"""A ROS 1 bag's reader checks the index entries of the topics it reads against their records;
damage in a record of a topic it does not read leaves what it reads exactly as in the intact
bag (the damaged topic is counted from the index, as chunks without a wanted topic are)."""

from __future__ import annotations

import struct
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import io_loggen as gen

from uwval.io import read_streams


def _tf_time_fields(data: bytes, conn: int) -> list[int]:
    """Offsets of the ``time`` values of /tf MessageData record headers."""
    out = []
    key = b"conn=" + struct.pack("<I", conn)
    at = data.find(key)
    while at >= 0:
        head = data[max(at - 40, 0) : at + 40]
        if b"op=\x02" in head and b"time=" in head:
            out.append(max(at - 40, 0) + head.index(b"time=") + 5)
        at = data.find(key, at + 1)
    return out


def test_damage_in_a_topic_not_read_changes_nothing_read(tmp_path: Path) -> None:
    from rosbags.rosbag1 import Reader

    p = gen.write_log(tmp_path / "log.bag", "bag", seconds=3.0, image_bytes=0)
    with Reader(p) as r:
        conn = next(c.id for c in r.connections if c.topic == gen.TF)
    topics = list(gen.POSE_TOPICS)
    intact = read_streams(p, topics)
    data = bytearray(p.read_bytes())
    fields = _tf_time_fields(bytes(data), conn)
    assert len(fields) > 10
    for at in fields[::7]:
        data[at] ^= 0x5A  # the /tf record no longer has its index entry's time
    p.write_bytes(bytes(data))
    damaged = read_streams(p, topics)
    for t in topics:
        assert np.array_equal(damaged[t].t, intact[t].t)
        assert np.array_equal(damaged[t].position, intact[t].position)
        assert np.array_equal(damaged[t].orientation, intact[t].orientation)
    # reading /tf itself checks its records: the damage is reported, not passed on
    tf_read = read_streams(p, [gen.TF + "#base_link"])[gen.TF + "#base_link"]
    assert tf_read.warnings
