"""--endpoint options fail cleanly before anything is written (review of issue 17)."""

from __future__ import annotations

from pathlib import Path

import pytest
from cli_runner import run_uwval


@pytest.mark.parametrize("endpoint", ["nohostport", "127.0.0.1:1"])
def test_teleop_with_a_bad_endpoint_leaves_no_unfinished_log(tmp_path: Path, endpoint: str) -> None:
    log = tmp_path / "t.mcap"
    out = run_uwval(
        "teleop", "--keys", "i@0:1", "--duration", "1", "--record", log, "--endpoint", endpoint
    )
    assert out.returncode == 2, out.stderr
    assert "Traceback" not in out.stderr
    assert not log.exists()


def test_simulate_endpoint_refuses_injected_faults(tmp_path: Path) -> None:
    out = run_uwval(
        "simulate", "--endpoint", "127.0.0.1:1", "--latency", "0.2", "--drop", "0.5",
        "--duration", "1", "-o", tmp_path / "x.mcap",
    )  # fmt: skip
    assert out.returncode == 2
    assert "--latency, --drop: injected faults apply to uwval's own loopback link" in out.stderr
    assert not (tmp_path / "x.mcap").exists()


def test_a_child_frame_on_a_topic_without_one_is_refused(tmp_path: Path) -> None:
    """/gazebo/model_rov_pose#foo used to be read whole, the '#foo' silently ignored."""
    log = tmp_path / "r.mcap"
    run_uwval("simulate", "--duration", "1", "-o", log, check=True)
    out = run_uwval(
        "compare", log, "--gazebo-topic", "/gazebo/model_rov_pose#foo",
        "--unity-topic", "/unity/model_rov_pose",
    )  # fmt: skip
    assert out.returncode == 2
    assert "which has no child frame" in out.stderr and "Traceback" not in out.stderr
