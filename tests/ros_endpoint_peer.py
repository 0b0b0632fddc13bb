"""Unity's real ROS-TCP-Endpoint 0.7.0 (ROS 1) with a rosmaster, for the tests that talk to it
(skipped, saying why, where it cannot run)."""

from __future__ import annotations

import contextlib
import os
import socket
import subprocess
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

ROSMASTER = Path("/usr/bin/rosmaster")


ROS_PYTHON = Path("/usr/bin/python3")


def _missing() -> str:
    """Why the real endpoint cannot run here ("" when it can)."""
    export = os.environ.get("UWVAL_ROS_TCP_ENDPOINT", "")
    if not export:
        return (
            "UWVAL_ROS_TCP_ENDPOINT is not set (an export of Unity's ROS-TCP-Endpoint 0.7.0, "
            "not available from a package registry)"
        )
    if not (Path(export) / "src" / "ros_tcp_endpoint").is_dir():
        return f"UWVAL_ROS_TCP_ENDPOINT={export} has no src/ros_tcp_endpoint"
    if not ROSMASTER.exists():
        return "no /usr/bin/rosmaster (Debian package ros-core)"
    check = subprocess.run(
        [str(ROS_PYTHON), "-c", "import rospy, geometry_msgs.msg"],
        capture_output=True,
        timeout=30,
    )
    if check.returncode != 0:
        return "rospy/geometry_msgs not importable by /usr/bin/python3 (python3-rospy)"
    return ""


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _wait_port(port: int, proc: subprocess.Popen[bytes], what: str, timeout: float) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            raise RuntimeError(f"{what} exited with {proc.returncode}")
        with contextlib.suppress(OSError), socket.create_connection(("127.0.0.1", port), 0.2):
            return
        time.sleep(0.05)
    raise RuntimeError(f"{what} did not listen on {port} within {timeout} s")


class RosEndpoint:
    """A running rosmaster + ROS-TCP-Endpoint pair and the environment of its ROS nodes."""

    def __init__(self, port: int, env: dict[str, str], tmp: Path) -> None:
        self.host = "127.0.0.1"
        self.port = port
        self.env = env
        self.tmp = tmp

    def ros_script(self, name: str, source: str, *args: str) -> subprocess.Popen[str]:
        """Start a rospy script with Debian's python3, stdout captured as text."""
        path = self.tmp / f"{name}.py"
        path.write_text(source)
        return subprocess.Popen(
            [str(ROS_PYTHON), str(path), *args],
            env=self.env,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )


@pytest.fixture(scope="module")
def ros_endpoint(tmp_path_factory: pytest.TempPathFactory) -> Iterator[RosEndpoint]:
    """rosmaster --core and the real endpoint on free loopback ports (or a skip, with why)."""
    why = _missing()
    if why:
        pytest.skip(why)
    tmp = tmp_path_factory.mktemp("ros")
    master_port, port = free_port(), free_port()
    env = dict(os.environ)
    env.update(
        ROS_IP="127.0.0.1",
        ROS_MASTER_URI=f"http://127.0.0.1:{master_port}",
        ROS_HOME=str(tmp / "ros_home"),
        ROS_LOG_DIR=str(tmp / "ros_log"),
        PYTHONPATH=str(Path(os.environ["UWVAL_ROS_TCP_ENDPOINT"]) / "src"),
    )
    procs: list[subprocess.Popen[bytes]] = []
    try:
        master = subprocess.Popen(
            [str(ROSMASTER), "--core", "-p", str(master_port)],
            env=env,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
        procs.append(master)
        _wait_port(master_port, master, "rosmaster", 20)
        endpoint = subprocess.Popen(
            [
                str(ROS_PYTHON),
                "-m",
                "ros_tcp_endpoint.default_server_endpoint",
                "_tcp_ip:=127.0.0.1",
                f"_tcp_port:={port}",
            ],
            env=env,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
        procs.append(endpoint)
        _wait_port(port, endpoint, "ROS-TCP-Endpoint", 20)
        yield RosEndpoint(port, env, tmp)
    finally:
        for p in reversed(procs):
            p.terminate()
            try:
                p.wait(5)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()
