"""``uwval teleop``: scripted key sessions drive the vehicle; a live client sees the poses."""

from __future__ import annotations

import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from cli_runner import run_uwval as _uwval

from uwval.io import read_stream
from uwval.rotations import rpy_from_quat
from uwval.simulator.inputs import HeldKeys


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def test_held_keys_add_and_expire() -> None:
    held = HeldKeys(force_step=10.0, torque_step=1.0, hold_s=0.5)
    assert held.press("i", 0.0) and held.press("j", 0.1)
    assert not held.press("x", 0.1)
    f, tq = held.wrench(0.3)
    np.testing.assert_allclose(f, [10.0, 0, 0])
    np.testing.assert_allclose(tq, [0, 0, 1.0])
    f, tq = held.wrench(0.55)  # i released 0.55 s ago (> hold), j still held
    np.testing.assert_allclose(f, 0.0)
    np.testing.assert_allclose(tq, [0, 0, 1.0])


def test_scripted_session_moves_vehicle_forward_and_turns_left(tmp_path: Path) -> None:
    log = tmp_path / "tele.mcap"
    res = _uwval(
        "teleop",
        "--keys",
        "i@0:3;j@0:3",
        "--duration",
        "3",
        "--speed",
        "0",
        "--port",
        "0",
        "--record",
        str(log),
    )
    assert res.returncode == 0, res.stderr
    s = read_stream(log, "/gazebo/model_rov_pose")
    assert len(s) == 151
    assert s.position[-1, 0] > 0.1  # surge forward
    yaw = np.degrees(rpy_from_quat(s.orientation[-1:]))[0, 2]
    assert yaw > 1.0  # 'j' = yaw left, counter-clockwise from above


def test_without_terminal_or_script_is_a_clean_error() -> None:
    res = _uwval("teleop", "--port", "0")
    assert res.returncode == 2
    assert "needs a terminal" in res.stderr and "Traceback" not in res.stderr


def test_live_client_receives_poses_over_tcp() -> None:
    from uwval.bridge.unity_client import UnityConnection, decode_pose_frame

    port = _free_port()
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "uwval",
            "teleop",
            "--keys",
            "i@0:5",
            "--duration",
            "4",
            "--port",
            str(port),
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        stdin=subprocess.DEVNULL,
    )
    try:
        conn = UnityConnection(
            "127.0.0.1", port, subscriptions={"model_rov_pose": "geometry_msgs/PoseStamped"}
        )
        deadline = time.monotonic() + 20
        while True:
            try:
                conn.connect(timeout=2.0)
                break
            except Exception:
                if time.monotonic() > deadline:
                    raise
                time.sleep(0.2)
        stamps: list[int] = []
        xs: list[float] = []
        while len(stamps) < 30 and time.monotonic() < deadline:
            for frame in conn.poll(timeout=0.5):
                if frame.destination.rstrip("\0") == "model_rov_pose":
                    pose = decode_pose_frame(frame, "ROS2")
                    stamps.append(pose.stamp_ns)
                    xs.append(float(pose.position[0]))
        conn.close()
    finally:
        proc.wait(timeout=30)
    assert len(stamps) >= 30
    assert np.all(np.diff(stamps) > 0)  # in order, sim-time stamps
    assert xs[-1] > xs[0]  # surging forward while 'i' is held
    if proc.returncode != 0:
        pytest.fail(proc.stderr.read().decode() if proc.stderr else "teleop failed")


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        (("--duration", "nan"), "--duration"),
        (("--speed", "-1"), "--speed"),
        (("--speed", "nan"), "--speed"),
        (("--hold", "-1"), "--hold"),
        (("--force-step", "nan"), "--force-step"),
        (("--port", "99999"), "port"),
        (("--vehicle", "nautilus"), "nautilus"),
        (("--keys", "z@0:1"), "unknown teleop key 'z'"),
        (("--current", "a,b"), "--current"),
        (("--publish-rate", "0"), "publish rate"),
        (("--record", "/proc/uwval-no-such-dir/t.mcap"), "/proc/uwval-no-such-dir/t.mcap"),
    ],
)
def test_bad_input_is_one_clean_line(
    capsys: pytest.CaptureFixture[str], args: tuple[str, ...], needle: str
) -> None:
    from uwval.cli import main

    argv = ["--keys", "i@0:1", "--duration", "1", "--speed", "0", "--port", "0"]
    for opt, value in zip(args[::2], args[1::2], strict=True):
        if opt in argv:
            argv[argv.index(opt) + 1] = value
        else:
            argv += [opt, value]
    with pytest.raises(SystemExit) as stop:
        main(["teleop", *argv])
    err = capsys.readouterr().err
    assert stop.value.code == 2, err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("error:"), err
    assert needle in lines[0]


def test_keyboard_teleop_drives_a_live_simulator() -> None:
    """Typed keys -> held wrench and current on a real Simulator (the domain code the CLI
    only feeds with terminal input)."""
    from uwval.simulator import Simulator, load_vehicle
    from uwval.simulator.inputs import KeyboardTeleop

    sim = Simulator(load_vehicle("tethys"))
    kb = KeyboardTeleop(force_step=10.0, torque_step=1.0, hold_s=0.5, current=(0, 0, 0))
    assert kb.handle("i+", 0.0, sim)
    np.testing.assert_allclose(kb.current, [0, 0.1, 0])
    assert sim._force_override is not None and sim._current_override is not None
    np.testing.assert_allclose(sim._force_override, [10.0, 0, 0])
    np.testing.assert_allclose(sim._current_override, [0, 0.1, 0])
    sim.advance_to(int(1e9))
    assert sim.state[7] > 0  # surging forward
    assert kb.handle(" ", 0.1, sim)  # space releases every key
    np.testing.assert_allclose(sim._force_override, 0.0)
    assert not kb.handle("iq", 0.2, sim)  # q quits
