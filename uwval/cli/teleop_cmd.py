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
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from rich.console import Console

from uwval.cli import app
from uwval.cli.declare import Opt, declare_signature
from uwval.cli.simulate_cmd import parse_vector
from uwval.cli.simulate_endpoint import endpoint_topics, parse_endpoint
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


@dataclass(frozen=True)
class TeleopOptions:
    """What ``uwval teleop`` does, as one value (units: s, Hz, N, N m, m/s world ENU).

    ``keys`` is a scripted key session (None: the keyboard); ``record`` an MCAP of the
    Gazebo side; ``endpoint`` HOST:PORT of a running ROS-TCP endpoint to publish into
    (None: serve on ``host``:``port``)."""

    vehicle: str = "tethys"
    host: str = "127.0.0.1"
    port: int = 10000
    keys: str | None = None
    duration_s: float = 0.0
    current: tuple[float, float, float] = (0.0, 0.0, 0.0)
    force_step: float = 10.0
    torque_step: float = 1.0
    hold_s: float = 0.6
    publish_rate: float = 50.0
    speed: float = 1.0
    record: Path | None = None
    endpoint: str | None = None
    endpoint_namespace: str = ""

    def check(self) -> None:
        """One clear error before anything starts (``not (x >= 0)`` is also true for NaN)."""
        interactive = self.keys is None
        for option, value in (
            ("--duration", self.duration_s),
            ("--speed", self.speed),
            ("--hold", self.hold_s),
        ):
            if not (0 <= value < math.inf):
                raise ConfigError(f"{option} must be a finite number >= 0, got {value}")
        for option, value in (
            ("--force-step", self.force_step),
            ("--torque-step", self.torque_step),
        ):
            if not math.isfinite(value):
                raise ConfigError(f"{option} must be a finite number, got {value}")
        if interactive and not sys.stdin.isatty():
            raise ConfigError("uwval teleop needs a terminal for keys; use --keys for a script")
        if not interactive and self.duration_s <= 0:
            raise ConfigError("--keys needs --duration (seconds)")
        if self.speed <= 0 and interactive:
            raise ConfigError("--speed 0 (as fast as possible) works only with --keys")


#: Every option of ``uwval teleop``: (keyword, flags, kind, default, help).
TELEOP_OPTIONS: tuple[Opt, ...] = (
    Opt("vehicle", ("--vehicle",), str, "tethys", "Preset name, MODEL.sdf or VEHICLE.toml."),
    Opt("host", ("--host",), str, "127.0.0.1", "Address the endpoint binds."),
    Opt("port", ("--port",), int, 10000, "Endpoint port (0: a free port)."),
    Opt("keys", ("--keys",), str, None, "Scripted keys, e.g. 'i@0:5;j@2:3'."),
    Opt("duration", ("--duration",), float, 0.0, "Stop after S seconds (0: until q)."),
    Opt("current", ("--current",), str, "0,0,0", "Initial current CX,CY,CZ, m/s (ENU)."),
    Opt("force_step", ("--force-step",), float, 10.0, "Force per held key, N."),
    Opt("torque_step", ("--torque-step",), float, 1.0, "Torque per held key, N m."),
    Opt("hold", ("--hold",), float, 0.6,
        "A key counts as held this long after it was last seen, s."),
    Opt("publish_rate", ("--publish-rate",), float, 50.0, "Pose publish rate, Hz."),
    Opt("speed", ("--speed",), float, 1.0,
     "Sim time per wall second (0: as fast as possible, scripted runs only)."),
    Opt("record", ("--record",), Path, None, "Also record the Gazebo side here (MCAP)."),
    Opt("endpoint", ("--endpoint",), str, None, "Publish INTO a running ROS-TCP endpoint at "
     "HOST:PORT (Unity's ROS-TCP-Endpoint) as a ROS publisher, instead of serving on "
     "--host/--port."),
    Opt("endpoint_namespace", ("--endpoint-namespace",), str, "",
     "With --endpoint: ROS namespace of the topics (e.g. /gazebo)."),
)  # fmt: skip


def teleop(**kw: Any) -> None:
    """Drive the simulated vehicle live from the keyboard through the TCP bridge."""
    options = TeleopOptions(
        vehicle=kw["vehicle"],
        host=kw["host"],
        port=kw["port"],
        keys=kw["keys"],
        duration_s=kw["duration"],
        current=parse_vector(kw["current"], "current"),
        force_step=kw["force_step"],
        torque_step=kw["torque_step"],
        hold_s=kw["hold"],
        publish_rate=kw["publish_rate"],
        speed=kw["speed"],
        record=kw["record"],
        endpoint=kw["endpoint"],
        endpoint_namespace=kw["endpoint_namespace"],
    )
    run_teleop(options)


declare_signature(teleop, TELEOP_OPTIONS)
app.command(name="teleop")(teleop)


def run_teleop(options: TeleopOptions) -> None:
    """Run the live session of ``options`` until its duration, ``q`` or Ctrl-C."""
    from uwval.bridge.gazebo import EndpointPublisher, GazeboPublisher, run_live
    from uwval.bridge.server import BridgeServer
    from uwval.simulator import InputProfile, Simulator, constant_inputs, load_vehicle
    from uwval.simulator.inputs import KeyboardTeleop

    options.check()
    keys, duration, speed, hold = options.keys, options.duration_s, options.speed, options.hold_s
    force_step, torque_step, publish_rate = (
        options.force_step,
        options.torque_step,
        options.publish_rate,
    )
    record, endpoint = options.record, options.endpoint
    interactive = keys is None
    cur = np.array(options.current)
    inputs = (
        InputProfile.from_keys(keys, cur, force_step, torque_step)
        if keys is not None
        else constant_inputs((0, 0, 0), (0, 0, 0), cur)
    )
    sim = Simulator(load_vehicle(options.vehicle), inputs, publish_rate=publish_rate)
    keyboard = KeyboardTeleop(force_step, torque_step, hold, cur)
    server: BridgeServer | None = None
    publisher: GazeboPublisher | EndpointPublisher
    if endpoint is not None:
        # parsed and connected before the log is opened: a bad endpoint leaves no file
        h, p = parse_endpoint(endpoint)
        publisher = EndpointPublisher(
            h,
            p,
            topics=endpoint_topics(options.endpoint_namespace),
            on_message=lambda kind, text: console.print(
                f"endpoint {kind}: {text}", highlight=False, markup=False
            ),
        )
        console.print(
            f"publishing into the endpoint at {h}:{p} ({publisher.protocol}) on "
            f"{', '.join(publisher.topics.values())}"
        )
    else:
        server = BridgeServer(options.host, options.port).start()
        publisher = GazeboPublisher(server)
        h, p = server.address
        console.print(f"endpoint listening on {h}:{p} (connect Unity's ROS-TCP-Connector here)")
    writer: Any = None
    if record is not None:
        from uwval.io import open_writer

        try:
            writer = open_writer(record, format="mcap", metadata={"run": "teleop"})
        except BaseException:
            if isinstance(publisher, EndpointPublisher):
                publisher.close()
            if server is not None:
                server.stop()
            raise
    if interactive:
        console.print("keys: i , J L t b j l u o y n | +/- current | k/space stop | q quit")
    every = max(1, round(publish_rate))
    sent = 0

    def control(t_ns: int) -> bool:
        return keyboard.handle(_read_keys(), t_ns * 1e-9, sim)

    def status(t_ns: int, pos: np.ndarray, _quat: np.ndarray) -> None:
        nonlocal sent
        sent += 1
        if sent % every == 0:  # ~1 Hz
            f, tq = keyboard.held.wrench(t_ns * 1e-9)
            console.print(
                f"t {t_ns * 1e-9:7.2f} s  pos {np.round(pos, 2)}  force {f} N  "
                f"torque {tq} N m  current {np.round(keyboard.current, 2)} m/s",
                highlight=False,
            )

    try:
        with _cbreak(interactive):
            run_live(
                sim,
                publisher,
                publish_rate=publish_rate,
                duration_s=duration,
                speed=speed,
                control=control if interactive else None,
                writer=writer,
                on_tick=status if interactive else None,
            )
    except KeyboardInterrupt:
        pass
    finally:
        if server is not None:
            server.stop()
        else:
            assert isinstance(publisher, EndpointPublisher)
            publisher.close()
        if writer is not None:
            writer.close()
    console.print(
        f"published {publisher.seq // 2} ticks ({publisher.seq} poses)"
        + (f"; Gazebo side recorded to {record}" if record else "")
    )
