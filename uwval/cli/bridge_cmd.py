"""``uwval bridge ...``: the ROS-TCP endpoint, log replay and a Unity-like client.

- ``uwval bridge serve``: a ROS-TCP-Endpoint-compatible server (default 127.0.0.1:10000)
  that Unity projects (ROS-TCP-Connector v0.7) connect to.
- ``uwval bridge replay LOG``: serve a recorded Gazebo-side log to connecting Unity
  clients at recorded or scaled speed.
- ``uwval bridge unity``: a Unity-like client that connects to an endpoint, renders the
  received poses at a frame rate and records its transforms (and applied stamps) to a log.
"""

from __future__ import annotations

import logging
import time
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer
from rich.console import Console
from rich.logging import RichHandler
from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

from uwval.bridge.errors import BridgeError
from uwval.cli import app

if TYPE_CHECKING:
    from uwval.bridge.protocol import Protocol

bridge_app = typer.Typer(
    help="ROS-TCP bridge: endpoint server, log replay, Unity-like client.", no_args_is_help=True
)
app.add_typer(bridge_app, name="bridge")
console = Console(stderr=True)

HostOpt = Annotated[str, typer.Option(help="Address to bind/connect (loopback by default).")]
PortOpt = Annotated[int, typer.Option(help="TCP port (ROS-TCP-Endpoint's default 10000).")]
ProtocolOpt = Annotated[str, typer.Option(help="ROS2 (CDR bodies) or ROS1.")]


def _logging(verbose: bool) -> None:
    logging.basicConfig(
        level=logging.INFO if verbose else logging.WARNING,
        format="%(message)s",
        handlers=[RichHandler(console=console, show_path=False)],
        force=True,
    )


def _check_port(port: int) -> int:
    if not 0 <= port <= 65535:
        raise BridgeError(f"--port must be 0-65535, got {port}")
    return port


def _check_seconds(value: float, option: str, *, zero_ok: bool) -> float:
    """A finite number of seconds, > 0 (or >= 0 with ``zero_ok``), else a clean error."""
    ok = value >= 0 if zero_ok else value > 0
    if not (ok and value < float("inf")):
        raise BridgeError(
            f"{option} must be a finite number of seconds "
            f"{'>= 0' if zero_ok else '> 0'}, got {value}"
        )
    return value


def _protocol(name: str) -> Protocol:
    from uwval.bridge.protocol import ProtocolError, check_protocol

    try:
        return check_protocol(name.upper())
    except ProtocolError as exc:
        raise BridgeError(f"--protocol: {exc}") from None


@bridge_app.command("serve")
def serve(
    host: HostOpt = "127.0.0.1",
    port: PortOpt = 10000,
    protocol: ProtocolOpt = "ROS2",
    queue_size: Annotated[int, typer.Option(help="Per-client outgoing queue bound.")] = 1024,
    max_frame: Annotated[int, typer.Option(help="Largest accepted frame payload, bytes.")] = 16
    * 1024
    * 1024,
    max_clients: Annotated[
        int,
        typer.Option(
            help="Simultaneous connections (one I/O thread serves all). When all are taken, a "
            "connection that registered nothing and was silent 2 s gives its slot to the new "
            "one; otherwise the new one is closed at once."
        ),
    ] = 64,
    unused_timeout: Annotated[
        float,
        typer.Option(
            help="Close a connection that registers no topic or service within this many "
            "seconds (0: never)."
        ),
    ] = 10.0,
    idle_timeout: Annotated[
        float,
        typer.Option(
            help="Close a connection silent (no frame, no keepalive; ROS-TCP-Connector sends "
            "one every second) for this many seconds (0: never)."
        ),
    ] = 0.0,
    duration: Annotated[
        float, typer.Option(help="Stop after this many seconds (0: run until Ctrl-C).")
    ] = 0.0,
    verbose: Annotated[
        bool, typer.Option("--verbose/--quiet", help="Log connections and registrations.")
    ] = True,
) -> None:
    """Run the ROS-TCP endpoint that Unity's ROS-TCP-Connector connects to.

    Limits (a client breaking one gets an __error, or is closed): --max-clients connections,
    --unused-timeout and --idle-timeout;
    a frame's payload at most --max-frame bytes and its destination 1 KiB; a system command
    (__subscribe, __log...) at most 64 KiB; topic and message names at most 1 KiB; 256
    registrations per client; --queue-size outgoing frames per client (oldest dropped).
    """
    from uwval.bridge.server import BridgeServer, use_mmap_for_large_buffers

    _check_port(port)
    _check_seconds(duration, "--duration", zero_ok=True)
    _check_seconds(unused_timeout, "--unused-timeout", zero_ok=True)
    _check_seconds(idle_timeout, "--idle-timeout", zero_ok=True)
    use_mmap_for_large_buffers()  # memory comes back when hostile clients leave
    _logging(verbose)
    server = BridgeServer(
        host,
        port,
        protocol=_protocol(protocol),
        queue_size=queue_size,
        max_frame=max_frame,
        max_clients=max_clients,
        unused_timeout=unused_timeout or None,
        idle_timeout=idle_timeout or None,
    ).start()
    console.print(
        f"[green]ROS-TCP endpoint[/] listening on {host}:{server.port} "
        f"({server.protocol}); Ctrl-C to stop"
    )
    t_end = time.monotonic() + duration if duration > 0 else float("inf")
    try:
        while time.monotonic() < t_end:
            time.sleep(0.1)
    except KeyboardInterrupt:
        pass
    finally:
        server.stop()
    for c in server.closed_clients():
        console.print(
            f"client {c.client_id} {c.address}: in {c.frames_in} out {c.frames_out} "
            f"dropped {c.dropped} ({c.closed_reason})"
        )


@bridge_app.command("replay")
def replay(
    log: Annotated[Path, typer.Argument(help="Log with the Gazebo-side topics.")],
    host: HostOpt = "127.0.0.1",
    port: PortOpt = 10000,
    protocol: ProtocolOpt = "ROS2",
    speed: Annotated[
        float, typer.Option(help="Playback speed factor (0: as fast as possible).")
    ] = 1.0,
    loops: Annotated[int, typer.Option(help="Passes over the log (0: until Ctrl-C).")] = 1,
    wait: Annotated[float, typer.Option(help="Seconds to wait for a subscriber first.")] = 60.0,
    topic: Annotated[
        list[str] | None,
        typer.Option(help="Log topic to replay (repeatable; default the two /gazebo topics)."),
    ] = None,
    verbose: Annotated[bool, typer.Option("--verbose/--quiet")] = False,
) -> None:
    """Serve a recorded Gazebo-side log to connecting Unity clients."""
    from uwval.bridge.replay import (
        DEFAULT_REPLAY_TOPICS,
        check_replay_options,
        load_replay_ticks,
        replay_log,
    )
    from uwval.bridge.server import BridgeServer

    _check_port(port)
    check_replay_options(speed, loops)
    _check_seconds(wait, "--wait", zero_ok=True)
    proto = _protocol(protocol)
    _logging(verbose)
    topics = tuple(topic) if topic else DEFAULT_REPLAY_TOPICS
    if not log.exists():
        raise BridgeError(f"{log}: no such file or directory")
    ticks = load_replay_ticks(log, topics)  # bad logs fail before the endpoint opens
    with BridgeServer(host, port, protocol=proto) as server:
        console.print(
            f"replaying {log} on {host}:{server.port} ({server.protocol}) at "
            f"{speed:g}x; waiting up to {wait:g} s for a Unity client"
        )
        with Progress(
            TextColumn("{task.description}"),
            BarColumn(),
            TextColumn("{task.completed}/{task.total} ticks"),
            TimeElapsedColumn(),
            console=console,
        ) as progress:
            task = progress.add_task("replay", total=None)

            def on_progress(done: int, total: int) -> None:
                progress.update(task, completed=done, total=total)

            try:
                stats = replay_log(
                    log,
                    server,
                    topics=topics,
                    speed=speed,
                    loops=loops,
                    wait_for_subscriber_s=wait if wait > 0 else None,
                    progress=on_progress,
                    ticks=ticks,
                )
            except KeyboardInterrupt:
                console.print("[yellow]replay interrupted[/]")
                return
    console.print(
        f"[green]replayed[/] {stats.ticks} ticks, {stats.published} messages "
        f"({stats.delivered} deliveries) in {stats.wall_time_s:.2f} s"
    )


@bridge_app.command("unity")
def unity(
    output: Annotated[Path, typer.Option("-o", "--output", help="MCAP log to write.")],
    host: HostOpt = "127.0.0.1",
    port: PortOpt = 10000,
    protocol: ProtocolOpt = "ROS2",
    duration: Annotated[float, typer.Option(help="Seconds to run.")] = 10.0,
    frame_rate: Annotated[float, typer.Option(help="Render loop rate, Hz.")] = 60.0,
    unity_map: Annotated[str, typer.Option(help="unity-flu or unity-enu.")] = "unity-flu",
    clock_offset: Annotated[float, typer.Option(help="Unity clock offset, s.")] = 0.0,
) -> None:
    """Run a Unity-like client against an endpoint and record what it renders."""
    from uwval.bridge.recorder import BridgeRecorder, open_mcap_writer
    from uwval.bridge.unity_client import UnityClient

    _check_port(port)
    _check_seconds(duration, "--duration", zero_ok=False)
    client = UnityClient(
        host,
        port,
        unity_map=unity_map,
        frame_rate=frame_rate,
        clock_offset_s=clock_offset,
        protocol=_protocol(protocol),
    )
    recorder = BridgeRecorder(open_mcap_writer(output), unity_map=unity_map)
    try:
        applied = client.run_realtime(
            duration,
            on_frame=lambda tr: recorder.unity_pose(
                tr.topic, tr.unity_t_ns, tr.position, tr.orientation, tr.applied_stamp_ns
            ),
        )
    finally:
        recorder.close()
    console.print(
        f"[green]wrote[/] {output}: {len(applied)} transforms, "
        f"{client.received} messages received, {client.connection.connects} "
        f"connection(s)"
    )
    if client.connection.connects == 0:
        raise BridgeError(
            f"never connected to an endpoint at {host}:{port} ({output} holds no Unity transforms)"
        )


@bridge_app.command("scan")
def scan(
    log: Annotated[Path, typer.Argument(help="MCAP log, possibly cut off by a crash.")],
) -> None:
    """Say whether a recorded MCAP is complete, or what survived a crash (per topic)."""
    from uwval.bridge.recorder import scan_mcap

    if not log.exists():
        raise BridgeError(f"{log}: no such file or directory")
    report = scan_mcap(log)
    print(report.describe())
    for topic, n in sorted(report.messages.items()):
        print(f"  {topic}: {n}")
    if not report.complete:
        raise typer.Exit(1)
