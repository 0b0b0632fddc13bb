"""Issue 14, data safety: SIGTERM or Ctrl-C to a process running tasks on the local executor
stops its worker processes; a worker whose parent was SIGKILLed exits by itself."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]

DRIVER = """
import signal, sys
# a process started as a shell's background job inherits SIGINT ignored (bash does this when
# job control is off), and Python then installs no KeyboardInterrupt handler: this driver
# stands for a foreground run, where Ctrl-C raises KeyboardInterrupt
signal.signal(signal.SIGINT, signal.default_int_handler)
from executor_tasks import spin_forever
from uwval.batch.executors import run_tasks
pid_dir = sys.argv[1]
run_tasks(spin_forever, [(i, pid_dir) for i in range(4)], [str(i) for i in range(4)],
          executor="local", workers=2, progress=False)
"""


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    # a zombie is dead for our purpose (its parent has not reaped it yet)
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return False
    return stat.rsplit(")", 1)[1].split()[0] != "Z"


def _start(tmp_path: Path) -> tuple[subprocess.Popen[bytes], list[int]]:
    proc = subprocess.Popen(
        [sys.executable, "-X", "faulthandler", "-c", DRIVER, str(tmp_path)],
        cwd=ROOT / "tests",  # executor_tasks is a module there
        stdin=subprocess.DEVNULL,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
    )
    for _ in range(600):  # up to 60 s for two spawned workers to start under load
        pids = [int(p.stem) for p in tmp_path.glob("*.pid")]
        if len(pids) == 2:
            return proc, pids
        if proc.poll() is not None:
            break
        time.sleep(0.1)
    proc.kill()
    pytest.fail(f"workers never started: {proc.communicate()[1].decode()[-2000:]}")


def _communicate_or_dump(proc: subprocess.Popen[bytes], timeout: float = 60.0) -> None:
    """Wait for the driver to exit; if it hangs, fail with every one of its threads' stacks
    (faulthandler prints them on SIGABRT), so that a hang says where it is."""
    try:
        proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        proc.send_signal(signal.SIGABRT)
        _out, err = proc.communicate()
        stacks = err.decode()[-6000:]
        pytest.fail(f"the driver did not exit within {timeout} s; its threads:\n{stacks}")


def _wait_gone(pids: list[int], seconds: float = 30.0) -> list[int]:
    for _ in range(int(seconds * 10)):
        left = [p for p in pids if _alive(p)]
        if not left:
            return []
        time.sleep(0.1)
    return left


def _cleanup(pids: list[int]) -> None:
    for p in pids:
        if _alive(p):
            os.kill(p, signal.SIGKILL)


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_signal_to_the_parent_stops_its_workers(tmp_path: Path, sig: signal.Signals) -> None:
    proc, pids = _start(tmp_path)
    try:
        proc.send_signal(sig)
        _communicate_or_dump(proc)
        assert proc.returncode == (143 if sig == signal.SIGTERM else 1) or proc.returncode < 0
        assert _wait_gone(pids) == []
    finally:
        proc.kill()
        _cleanup(pids)


def test_workers_of_a_killed_parent_exit_by_themselves(tmp_path: Path) -> None:
    proc, pids = _start(tmp_path)
    try:
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=60)
        assert _wait_gone(pids) == []
    finally:
        _cleanup(pids)
