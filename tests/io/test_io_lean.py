"""Issue 15 (io): a selected topic keeps only its own bytes, whatever else the chunks hold.

With topics interleaved in every chunk (every real log), the raw buffer of a selected topic
must hold exactly its messages' payloads: not the chunk range from its first to its last
message (which is nearly the whole chunk), and nothing of an image topic beside it.
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import io_loggen as gen

from uwval.io import read_streams
from uwval.io.containers import scan_log
from uwval.io.decode import decode_poses

FORMATS = [("mcap", ".mcap"), ("bag", ".bag"), ("rosbag2-sqlite3", ""), ("rosbag2-mcap", "")]


@pytest.mark.parametrize(("fmt", "suffix"), FORMATS)
def test_selected_topic_buffers_hold_only_their_payloads(
    tmp_path: Path, fmt: str, suffix: str
) -> None:
    p = gen.write_log(
        tmp_path / f"img{suffix}", fmt, seconds=2.0, image_bytes=20_000, chunk_size=256 * 1024
    )
    log = scan_log(p, [gen.GAZEBO, gen.UNITY])
    for t in gen.POSE_TOPICS:
        raw = log.raw[t]
        assert raw.buf.shape[0] == int(raw.length.sum())  # nothing but its own messages
        # and every payload is where its offset says (fast decode == rosbags decode)
        fast = decode_poses(raw)
        slow = decode_poses(raw, fast=False)
        np.testing.assert_array_equal(fast.pose, slow.pose)
        np.testing.assert_array_equal(fast.stamp, slow.stamp)


@pytest.mark.parametrize(("fmt", "suffix"), FORMATS)
def test_an_image_topic_changes_nothing_read(tmp_path: Path, fmt: str, suffix: str) -> None:
    with_img = gen.write_log(tmp_path / f"a{suffix}", fmt, seconds=2.0, image_bytes=30_000)
    without = gen.write_log(tmp_path / f"b{suffix}", fmt, seconds=2.0, image_bytes=0)
    a = read_streams(with_img, list(gen.POSE_TOPICS))
    b = read_streams(without, list(gen.POSE_TOPICS))
    for t in gen.POSE_TOPICS:
        np.testing.assert_array_equal(a[t].t, b[t].t)
        np.testing.assert_array_equal(a[t].position, b[t].position)
        np.testing.assert_array_equal(a[t].orientation, b[t].orientation)
        np.testing.assert_array_equal(a[t].applied_stamp, b[t].applied_stamp)
        assert not a[t].warnings and not a[t].dropped


def test_compare_of_one_log_scans_it_once(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Issue 15: the topic list and the read were two scans; now one (the real scanner runs,
    wrapped only to count its calls)."""
    import uwval.io.reader as reader
    from uwval.comparison.logs import compare_logs

    p = gen.write_log(tmp_path / "run.mcap", "mcap", seconds=2.0, image_bytes=5000)
    calls: list[object] = []
    real = reader.scan_log

    def counting(*args: Any, **kwargs: Any) -> Any:
        calls.append(args[0])
        return real(*args, **kwargs)

    monkeypatch.setattr(reader, "scan_log", counting)
    res = compare_logs(p)
    assert list(res.results) == ["model_rov_pose"]
    assert len(calls) == 1
