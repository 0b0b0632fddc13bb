"""``uwval teleop``: drive a live run from the keyboard, as teleop_wrench_keyboard does.

The simulator runs on the wall clock and publishes the vehicle and camera poses through a
ROS-TCP-Endpoint-compatible server, so a real Unity project (or ``uwval bridge unity``)
connected to it shows the vehicle live. Keys (uwval.simulator.inputs.TELEOP_KEYS): ``i``/``,``
surge, ``J``/``L`` sway, ``t``/``b`` heave, ``j``/``l`` yaw, ``u``/``o`` roll, ``y``/``n``
pitch; ``+``/``-`` change the current towards north by 0.1 m/s; ``k`` or space stops; ``q``
quits. A held key (terminal auto-repeat) keeps its wrench increment applied; released for
``--hold`` seconds, it stops. ``--keys "i@0:5;j@2:3"`` replays a scripted session instead.
"""

from __future__ import annotations

import contextlib
import math
import os
import select
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Annotated, Any

import numpy as np
import typer
from rich.console import Console

from uwval.cli import app
from uwval.cli.simulate_cmd import parse_vector
from uwval.errors import ConfigError

console = Console()


@contextlib.contextmanager
def _cbreak(enabled: bool) -> Iterator[None]:
    """Read single key presses without Enter (restores the terminal on exit)."""
    if not enabled:
        yield
        return
    import termios
    import tty

    fd = sys.stdin.fileno()
    old = termios.tcgetattr(fd)
    try:
        tty.setcbreak(fd)
        yield
    finally:
        termios.tcsetattr(fd, termios.TCSADRAIN, old)


def _read_keys() -> str:
    """Keys typed since the last call (non-blocking)."""
    out = ""
    while select.select([sys.stdin], [], [], 0)[0]:
        ch = os.read(sys.stdin.fileno(), 32).decode(errors="ignore")
        if not ch:
            break
        out += ch
    return out


class HeldKeys:
    """Wrench from keys held down: each key stays active ``hold_s`` after its last repeat."""

    def __init__(self, force_step: float, torque_step: float, hold_s: float) -> None:
        from uwval.simulator.inputs import TELEOP_KEYS

        self.keys = TELEOP_KEYS
        self.force_step = force_step
        self.torque_step = torque_step
        self.hold_s = hold_s
        self.last_seen: dict[str, float] = {}

    def press(self, key: str, now: float) -> bool:
        """Record a key press; False when the key is not a teleop key."""
        if key not in self.keys:
            return False
        self.last_seen[key] = now
        return True

    def clear(self) -> None:
        self.last_seen.clear()

    def wrench(self, now: float) -> tuple[np.ndarray, np.ndarray]:
        """(force N, torque N m) in the body frame from the keys held at ``now``."""
        force, torque = np.zeros(3), np.zeros(3)
        for key, seen in self.last_seen.items():
            if now - seen <= self.hold_s:
                ch, axis, sign = self.keys[key]
                if ch == 0:
                    force[axis] += sign * self.force_step
                else:
                    torque[axis] += sign * self.torque_step
        return force, torque


@app.command()
def teleop(
    vehicle: Annotated[
        str, typer.Option(help="Preset name, MODEL.sdf or VEHICLE.toml.")
    ] = "tethys",
    host: Annotated[str, typer.Option(help="Address the endpoint binds.")] = "127.0.0.1",
    port: Annotated[int, typer.Option(help="Endpoint port (0: a free port).")] = 10000,
    keys: Annotated[str | None, typer.Option(help="Scripted keys, e.g. 'i@0:5;j@2:3'.")] = None,
    duration: Annotated[float, typer.Option(help="Stop after S seconds (0: until q).")] = 0.0,
    current: Annotated[str, typer.Option(help="Initial current CX,CY,CZ, m/s (ENU).")] = "0,0,0",
    force_step: Annotated[float, typer.Option(help="Force per held key, N.")] = 10.0,
    torque_step: Annotated[float, typer.Option(help="Torque per held key, N m.")] = 1.0,
    hold: Annotated[
        float, typer.Option(help="A key counts as held this long after it was last seen, s.")
    ] = 0.6,
    publish_rate: Annotated[float, typer.Option(help="Pose publish rate, Hz.")] = 50.0,
    speed: Annotated[
        float,
        typer.Option(help="Sim time per wall second (0: as fast as possible, scripted runs only)."),
    ] = 1.0,
    record: Annotated[
        Path | None, typer.Option(help="Also record the Gazebo side here (MCAP).")
    ] = None,
) -> None:
    """Drive the simulated vehicle live from the keyboard through the TCP bridge."""
    from uwval.bridge.gazebo import GazeboPublisher
    from uwval.bridge.server import BridgeServer
    from uwval.simulator import InputProfile, Simulator, constant_inputs, load_vehicle

    interactive = keys is None
    # Checked before anything starts: ``not (x >= 0)`` is also true for NaN.
    for option, value in (("--duration", duration), ("--speed", speed), ("--hold", hold)):
        if not (0 <= value < math.inf):
            raise ConfigError(f"{option} must be a finite number >= 0, got {value}")
    for option, value in (("--force-step", force_step), ("--torque-step", torque_step)):
        if not math.isfinite(value):
            raise ConfigError(f"{option} must be a finite number, got {value}")
    if interactive and not sys.stdin.isatty():
        raise ConfigError("uwval teleop needs a terminal for keys; use --keys for a script")
    if not interactive and duration <= 0:
        raise ConfigError("--keys needs --duration (seconds)")
    if speed <= 0 and interactive:
        raise ConfigError("--speed 0 (as fast as possible) works only with --keys")
    cur = np.array(parse_vector(current, "current"))
    inputs = (
        InputProfile.from_keys(keys, cur, force_step, torque_step)
        if keys is not None
        else constant_inputs((0, 0, 0), (0, 0, 0), cur)
    )
    sim = Simulator(load_vehicle(vehicle), inputs, publish_rate=publish_rate)
    held = HeldKeys(force_step, torque_step, hold)
    writer: Any = None
    if record is not None:
        from uwval.io import open_writer

        writer = open_writer(record, format="mcap", metadata={"run": "teleop"})
    server = BridgeServer(host, port).start()
    publisher = GazeboPublisher(server)
    h, p = server.address
    console.print(f"endpoint listening on {h}:{p} (connect Unity's ROS-TCP-Connector here)")
    if interactive:
        console.print("keys: i , J L t b j l u o y n | +/- current | k/space stop | q quit")
    period_ns = round(1e9 / publish_rate)
    t_wall0 = time.perf_counter()
    sent = 0
    try:
        with _cbreak(interactive):
            t_ns = 0
            while duration <= 0 or t_ns <= int(duration * 1e9):
                if interactive:
                    now = t_ns * 1e-9
                    for ch in _read_keys():
                        if ch == "q":
                            raise KeyboardInterrupt
                        if ch in " k":
                            held.clear()
                        elif ch in "+-":
                            cur[1] += 0.1 if ch == "+" else -0.1
                            sim.set_current(cur)
                        else:
                            held.press(ch, now)
                    sim.set_wrench(*held.wrench(now))
                for tick_t, vp, vq, cp, cq in sim.advance_to(t_ns):
                    publisher.publish_tick(
                        (tick_t, {"model_rov_pose": (vp, vq), "gui_camera_pose": (cp, cq)})
                    )
                    sent += 1
                    if writer is not None:
                        writer.write_pose("/gazebo/model_rov_pose", tick_t, vp, vq, "world")
                        writer.write_pose("/gazebo/gui_camera_pose", tick_t, cp, cq, "world")
                    if interactive and sent % max(1, round(publish_rate)) == 0:  # ~1 Hz
                        f, tq = held.wrench(tick_t * 1e-9)
                        console.print(
                            f"t {tick_t * 1e-9:7.2f} s  pos {np.round(vp, 2)}  "
                            f"force {f} N  torque {tq} N m  current {np.round(cur, 2)} m/s",
                            highlight=False,
                        )
                t_ns += period_ns
                if speed > 0:  # pace sim time to the wall clock
                    lag = t_ns * 1e-9 / speed - (time.perf_counter() - t_wall0)
                    if lag > 0:
                        time.sleep(lag)
    except KeyboardInterrupt:
        pass
    finally:
        server.stop()
        if writer is not None:
            writer.close()
    console.print(
        f"published {sent} ticks ({sent * 2} poses)"
        + (f"; Gazebo side recorded to {record}" if record else "")
    )
