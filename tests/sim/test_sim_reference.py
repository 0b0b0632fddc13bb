"""``uwval simulate`` logs the same poses as before the block write path (issue 15).

Reference digests: the first 4 s of ``uwval simulate --duration 3600 --format F`` (default
options otherwise) as written by the code before issue 15's recorder work (commit 8ecf709,
per-message ``add_message`` / rosbags writes): SHA-256 over topics (sorted), then each topic's
messages in log-time order as (log time int64 LE, raw bytes). A 5 s run's first 4 s are the
same messages (the session is seeded and frame/arrival times depend only on the clock).
"""

from __future__ import annotations

import hashlib
import json
import struct
from pathlib import Path
from typing import Any

import pytest
from cli_runner import run_uwval

#: CDR formats (MCAP, rosbag2 sqlite3 / MCAP storage) carry the same bytes; ROS 1 its own.
#: The Unity side changed with issues 31.4 / 32.1 (ROS-TCP-Connector's reader, a vsync phase per
#: seed, the transport calibrated for two topics); before: cdr 803c3708..., ros1 859658ee....
REFERENCE = {
    "cdr": "b1f59cf2d7090a0e440a13e344644bcf04717e71b0a6cba76e2b99015e815888",
    "ros1": "9971d3fa12f345b498abf00884e44544d2f0adc987ad1494b1b0891ba3aa531a",
}
#: The Gazebo side alone, unchanged since commit 8ecf709 (the digest of its topics only).
GAZEBO_REFERENCE = {
    "cdr": "bd0f6efd59de49a3bec2dfc2f0b17af8ef3895082f649728a5495d5d89888197",
    "ros1": "597925181a8ddc06d1df7089c83985f9953cb446b2296da5f3450e14d5f67a87",
}
COUNTS = {  # messages per topic with log time <= 4 s
    "/gazebo/model_rov_pose": 201,
    "/gazebo/gui_camera_pose": 201,
    "/unity/model_rov_pose": 233,
    "/unity/model_rov_pose/applied_stamp": 233,
    "/unity/gui_camera_pose": 230,
    "/unity/gui_camera_pose/applied_stamp": 230,
}
SUFFIX = {"mcap": ".mcap", "rosbag2": "", "rosbag2-mcap": "", "rosbag1": ".bag"}


def messages(path: Path, until_ns: int) -> dict[str, list[tuple[int, bytes]]]:
    """(log time, raw bytes) per topic up to ``until_ns``, read by mcap or rosbags."""
    per: dict[str, list[tuple[int, bytes]]] = {}
    if path.suffix == ".mcap":
        from mcap.reader import make_reader

        with open(path, "rb") as fh:
            for _, ch, m in make_reader(fh).iter_messages(log_time_order=False):
                if m.log_time <= until_ns:
                    per.setdefault(ch.topic, []).append((m.log_time, bytes(m.data)))
    else:
        from rosbags.highlevel import AnyReader

        with AnyReader([path]) as reader:
            for conn, t, raw in reader.messages(stop=until_ns + 1):
                if not conn.topic.startswith("/uwval/"):  # ROS 1 metadata message
                    per.setdefault(conn.topic, []).append((t, bytes(raw)))
    return per


def digest(per: dict[str, list[tuple[int, bytes]]]) -> str:
    h = hashlib.sha256()
    for topic in sorted(per):
        h.update(topic.encode())
        for log_time, data in sorted(per[topic], key=lambda m: m[0]):
            h.update(struct.pack("<q", log_time))
            h.update(data)
    return h.hexdigest()


@pytest.mark.parametrize("fmt", ["mcap", "rosbag1", "rosbag2"])
def test_simulate_logs_the_poses_it_logged_before(tmp_path: Path, fmt: str) -> None:
    log = tmp_path / f"run{SUFFIX[fmt]}"
    res = run_uwval("simulate", "--duration", "5", "--format", fmt, "-o", log)
    assert res.returncode == 0, res.stderr
    per = messages(log, 4_000_000_000)
    assert {k: len(v) for k, v in per.items()} == COUNTS
    enc = "ros1" if fmt == "rosbag1" else "cdr"
    assert (
        digest({k: v for k, v in per.items() if k.startswith("/gazebo")}) == GAZEBO_REFERENCE[enc]
    )
    assert digest(per) == REFERENCE[enc]


def _strip_sources(obj: Any) -> Any:
    if isinstance(obj, dict):
        return {
            k: _strip_sources(v) for k, v in obj.items() if k not in ("source", "sources", "log")
        }
    if isinstance(obj, list):
        return [_strip_sources(v) for v in obj]
    return obj


def test_compare_gives_the_same_metrics_on_the_block_and_per_message_logs(tmp_path: Path) -> None:
    """One run (force and torque, a real Unity side) recorded through the block path (as
    ``uwval simulate`` does) and through the per-message path: equal messages, and ``uwval
    compare`` (both pairs) reports the same numbers on both."""
    from per_message import PerMessage

    from uwval.bridge.experiment import RunJob, SessionOptions, run_one, ticks_of
    from uwval.bridge.recorder import open_log_writer
    from uwval.bridge.session import BridgeSession
    from uwval.simulator import RunSpec, SimulationStream, constant_inputs, load_vehicle

    spec = RunSpec(
        name="ref",
        factors={"force": 10.0},
        vehicle=load_vehicle("tethys"),
        inputs=constant_inputs((10.0, 0.0, 0.0), (0.0, 0.0, 1.0), (0.0, 0.2, 0.0)),
        duration_s=6.0,
        seed=3,
        publish_rate=50.0,
    )
    opts = SessionOptions(
        transport="real-endpoint", frame_model="vsync", float32=True, clock_drift_ppm=20.0
    )
    blocks = tmp_path / "blocks.mcap"
    run_one(RunJob(spec, str(blocks), opts))
    per_message = tmp_path / "messages.mcap"
    stream = SimulationStream(spec.vehicle, spec.inputs, spec.duration_s, **spec.simulate_kwargs())
    with open_log_writer(per_message, "mcap") as writer:
        BridgeSession(PerMessage(writer), opts, seed=spec.seed).run(ticks_of(stream))
    a, b = messages(blocks, 2**62), messages(per_message, 2**62)
    assert a == b
    assert len(a["/unity/model_rov_pose"]) > 300
    results = []
    for log in (blocks, per_message):
        res = run_uwval("compare", log, "--json")
        assert res.returncode == 0, res.stderr
        results.append(_strip_sources(json.loads(res.stdout)))
    assert results[0] == results[1]
    assert results[0]["axes"]  # something was compared
