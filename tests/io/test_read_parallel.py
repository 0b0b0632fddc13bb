"""Topics decoded on two threads (large reads) give exactly what one thread gives, and the
error reported is the one of the first topic asked for, as before."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import io_loggen as gen

from uwval.errors import LogReadError
from uwval.io import reader

TOPICS = ["/gazebo/model_rov_pose", "/unity/model_rov_pose", "/tf#base_link"]


def _read(p: Path, topics: list[str], threshold: int, mp: pytest.MonkeyPatch) -> dict:
    mp.setattr(reader, "PARALLEL_DECODE_MIN", threshold)
    return reader.read_streams(p, topics)


@pytest.mark.parametrize("fmt", ["mcap", "bag"])
def test_threads_decode_what_one_thread_decodes(
    tmp_path: Path, fmt: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    p = gen.write_log(tmp_path / f"log.{fmt}", fmt, seconds=3.0, image_bytes=0)
    topics = TOPICS if fmt == "mcap" else TOPICS[:2]
    one = _read(p, topics, 10**12, monkeypatch)
    two = _read(p, topics, 1, monkeypatch)
    assert list(one) == list(two) == topics
    for t in topics:
        a, b = one[t], two[t]
        assert a.topic == b.topic and a.frame == b.frame and a.warnings == b.warnings
        assert np.array_equal(a.t, b.t)
        assert np.array_equal(a.position, b.position)
        assert np.array_equal(a.orientation, b.orientation)
        assert (a.applied_stamp is None) == (b.applied_stamp is None)
        if a.applied_stamp is not None:
            assert np.array_equal(a.applied_stamp, b.applied_stamp)


def test_the_first_topics_error_is_reported(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    p = gen.write_log(tmp_path / "log.mcap", "mcap", seconds=1.0, image_bytes=0)
    # the second topic is a std_msgs/Header topic: no pose; the third asks a missing child
    topics = ["/gazebo/model_rov_pose", "/unity/model_rov_pose/applied_stamp", "/tf#nobody"]
    errors = []
    for threshold in (10**12, 1):
        with pytest.raises(LogReadError) as exc:
            _read(p, topics, threshold, monkeypatch)
        errors.append(str(exc.value))
    assert errors[0] == errors[1]
    assert "has no pose" in errors[0]
