"""``uwval bridge ...``: the ROS-TCP endpoint, log replay and a Unity-like client.

- ``uwval bridge serve``: a ROS-TCP-Endpoint-compatible server (default 127.0.0.1:10000)
  that Unity projects (ROS-TCP-Connector v0.7) connect to.
- ``uwval bridge replay LOG``: serve a recorded Gazebo-side log to connecting Unity
  clients at recorded or scaled speed.
- ``uwval bridge unity``: a Unity-like client that connects to an endpoint (uwval's or
  Unity's real ROS-TCP-Endpoint; protocol from its handshake), renders the received poses at
  a frame rate and records its transforms (and applied stamps), the Gazebo-side poses it
  received and the clocks' relation (``uwval.clock`` metadata) to one log.
"""

from __future__ import annotations

import logging
import time
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Literal

import typer
from rich.console import Console
from rich.logging import RichHandler
from rich.markup import escape
from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

from uwval.bridge.errors import BridgeError
from uwval.cli import app

if TYPE_CHECKING:
    from uwval.bridge.protocol import Protocol
    from uwval.bridge.unity_client import UnityClient

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


#: ``--compat`` values -> (server compat, route): ``real-endpoint`` routes as the real endpoint
#: (everything to the newest connection), ``real-endpoint-subscribers`` keeps its rules but
#: serves every subscribed client.
_COMPAT_CHOICES = {
    "uwval": ("uwval", None),
    "real-endpoint": ("real-endpoint", "newest"),
    "real-endpoint-subscribers": ("real-endpoint", "subscribers"),
}


def _compat(name: str) -> tuple[str, str | None]:
    if name not in _COMPAT_CHOICES:
        raise BridgeError(f"--compat must be one of {', '.join(_COMPAT_CHOICES)}, got {name!r}")
    return _COMPAT_CHOICES[name]


@bridge_app.command("serve")
def serve(
    host: HostOpt = "127.0.0.1",
    port: PortOpt = 10000,
    protocol: Annotated[
        str | None,
        typer.Option(
            help="ROS2 (CDR bodies) or ROS1. Default: ROS2, or ROS1 with --compat real-endpoint "
            "(the ROS 1 release of ROS-TCP-Endpoint 0.7.0)."
        ),
    ] = None,
    queue_size: Annotated[int, typer.Option(help="Per-client outgoing queue bound.")] = 1024,
    max_frame: Annotated[int, typer.Option(help="Largest accepted frame payload, bytes.")] = 16
    * 1024
    * 1024,
    max_clients: Annotated[
        int,
        typer.Option(
            help="Simultaneous connections (one I/O thread serves all). When all are taken, a "
            "connection that registered nothing and was silent 2 s gives its slot to the new "
            "one, else the one that sent nothing but keepalives for longest (at least 2 s); "
            "otherwise the new one is closed at once."
        ),
    ] = 64,
    unused_timeout: Annotated[
        float,
        typer.Option(
            help="Close a connection that sends nothing (not even a keepalive) and registers "
            "no topic or service within this many seconds (0: never)."
        ),
    ] = 10.0,
    idle_timeout: Annotated[
        float,
        typer.Option(
            help="Close a connection silent (no frame, no keepalive; ROS-TCP-Connector sends "
            "one every second) for this many seconds (0: never)."
        ),
    ] = 5.0,
    compat: Annotated[
        str,
        typer.Option(
            help="uwval (forgiving) or real-endpoint: behave as Unity's ROS-TCP-Endpoint 0.7.0 "
            "(ROS1 handshake unless --protocol; closes on unknown commands and JSON keys, "
            "__error for unknown message classes, registrations kept across reconnects, own "
            "publications echoed, header.seq rewritten, everything sent to the newest "
            "connection), so an app tested here does not break on the real one. "
            "real-endpoint-subscribers: the same, but every subscribed client is served."
        ),
    ] = "uwval",
    known_package: Annotated[
        list[str] | None,
        typer.Option(
            help="With --compat real-endpoint: a message package the ROS side resolves besides "
            "the standard ones (repeatable)."
        ),
    ] = None,
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
    from uwval.bridge.server import BridgeServer

    _check_port(port)
    _check_seconds(duration, "--duration", zero_ok=True)
    _check_seconds(unused_timeout, "--unused-timeout", zero_ok=True)
    _check_seconds(idle_timeout, "--idle-timeout", zero_ok=True)
    _logging(verbose)
    server = BridgeServer(
        host,
        port,
        protocol=_protocol(protocol) if protocol is not None else None,
        queue_size=queue_size,
        max_frame=max_frame,
        max_clients=max_clients,
        unused_timeout=unused_timeout or None,
        idle_timeout=idle_timeout or None,
        compat=_compat(compat)[0],
        known_packages=frozenset(known_package or ()),
        route=_compat(compat)[1],
    ).start()
    console.print(
        f"[green]ROS-TCP endpoint[/] listening on {host}:{server.port} "
        f"({server.protocol}"
        f"{', as ROS-TCP-Endpoint 0.7.0, to ' + server.route if compat != 'uwval' else ''}); "
        "Ctrl-C to stop"
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


def _unity_topics(gazebo: list[str] | None, unity: list[str] | None) -> list[tuple[str, str]]:
    """(ROS topic subscribed, Unity-side log topic) pairs from the options, checked."""
    from uwval.bridge.options import DEFAULT_TOPICS
    from uwval.bridge.recorder import UNITY_PREFIX, log_topic

    topics = list(gazebo) if gazebo else list(DEFAULT_TOPICS)
    for t in topics:
        if not t.strip("/") or "//" in t or any(c.isspace() for c in t):
            raise BridgeError(f"--gazebo-topic {t!r}: not a ROS topic name")
    if unity and len(unity) != len(topics):
        raise BridgeError(
            f"--unity-topic given {len(unity)} time(s) for {len(topics)} --gazebo-topic(s): "
            "give one per Gazebo topic, in the same order"
        )
    names = list(unity) if unity else [t.strip("/").split("/")[-1] for t in topics]
    pairs = [(t, log_topic(UNITY_PREFIX, n)) for t, n in zip(topics, names, strict=True)]
    seen = [u for _, u in pairs]
    if len(set(seen)) != len(seen) or len(set(topics)) != len(topics):
        raise BridgeError(
            "--gazebo-topic/--unity-topic: each topic once (two Gazebo topics would share "
            f"Unity topics {seen}); name them with --unity-topic"
        )
    return pairs


@bridge_app.command("unity")
def unity(
    output: Annotated[Path, typer.Option("-o", "--output", help="MCAP log to write.")],
    host: HostOpt = "127.0.0.1",
    port: PortOpt = 10000,
    protocol: Annotated[
        str,
        typer.Option(
            help="auto (what the endpoint's handshake says), ROS1 or ROS2; an explicit one "
            "that differs from the endpoint's is an error."
        ),
    ] = "auto",
    gazebo_topic: Annotated[
        list[str] | None,
        typer.Option(
            help="ROS topic (PoseStamped) to subscribe to, repeatable; absolute names "
            "(/gazebo/model_rov_pose) are used and recorded as they are, relative ones are "
            "recorded under /gazebo/. Default: model_rov_pose and gui_camera_pose."
        ),
    ] = None,
    unity_topic: Annotated[
        list[str] | None,
        typer.Option(
            help="Log topic of the Unity transforms of each --gazebo-topic (same order); "
            "default /unity/<last part of the Gazebo topic>."
        ),
    ] = None,
    record_gazebo: Annotated[
        bool,
        typer.Option(help="Also record the Gazebo-side poses received, as received."),
    ] = True,
    clock: Annotated[
        str,
        typer.Option(
            help="Unity's clock: epoch (Unix time, comparable with ROS header stamps) or "
            "monotonic (time since boot). The log's 'uwval.clock' metadata maps one to the other."
        ),
    ] = "epoch",
    duration: Annotated[float, typer.Option(help="Seconds to run.")] = 10.0,
    frame_rate: Annotated[float, typer.Option(help="Render loop rate, Hz.")] = 60.0,
    unity_map: Annotated[str, typer.Option(help="unity-flu or unity-enu.")] = "unity-flu",
    clock_offset: Annotated[float, typer.Option(help="Unity clock offset, s.")] = 0.0,
) -> None:
    """Run a Unity-like client against an endpoint (uwval's or Unity's ROS-TCP-Endpoint) and
    record what it renders, and the Gazebo-side poses it receives, in one log.

    The endpoint's __log/__warn/__error texts are printed as they come; any __error makes
    the exit status 1. The log's 'uwval.clock' metadata records the Unity clock used and
    epoch_minus_monotonic_ns (Unix time minus monotonic time, ns), so stamps on either
    clock can be put on the other.
    """
    from uwval.bridge import protocol as wire
    from uwval.bridge.recorder import BridgeRecorder, log_topic, open_mcap_writer
    from uwval.bridge.unity_client import (
        ProtocolMismatchError,
        ReceivedPose,
        UnityClient,
    )

    _check_port(port)
    _check_seconds(duration, "--duration", zero_ok=False)
    proto: Protocol | Literal["auto"] = (
        "auto" if protocol.lower() == "auto" else _protocol(protocol)
    )
    if clock not in ("epoch", "monotonic"):
        raise BridgeError(f"--clock: expected epoch or monotonic, got {clock!r}")
    pairs = _unity_topics(gazebo_topic, unity_topic)
    unity_of = dict(pairs)

    def on_message(kind: str, text: str) -> None:
        style = {wire.ERROR: "red", wire.WARN: "yellow"}.get(kind, "dim")
        console.print(f"[{style}]endpoint {kind}:[/] {escape(text)}", highlight=False)

    client = UnityClient(
        host,
        port,
        topics=[t for t, _ in pairs],
        unity_map=unity_map,
        frame_rate=frame_rate,
        clock_offset_s=clock_offset,
        protocol=proto,
        clock="epoch" if clock == "epoch" else "monotonic",
        on_message=on_message,
    )
    e_m = client.epoch_minus_monotonic_ns
    clock_meta = {
        "unity_clock": clock,
        "unity_clock_offset_ns": str(round(clock_offset * 1e9)),
        "epoch_minus_monotonic_ns": str(e_m),
        "gazebo_log_time": "epoch receive time",
    }
    writer = open_mcap_writer(output)
    writer.add_metadata("uwval.clock", clock_meta)
    recorder = BridgeRecorder(writer, unity_map=unity_map)
    gazebo_of = {t: log_topic("/gazebo", t) for t, _ in pairs}

    def on_receive(pose: ReceivedPose) -> None:
        recorder.gazebo_pose(
            gazebo_of.get(pose.topic, pose.topic),
            pose.stamp_ns,
            pose.position,
            pose.orientation,
            log_time=pose.recv_wall_ns + e_m,
            frame_id=pose.frame_id,
        )

    if record_gazebo:
        client.on_receive = on_receive
    mismatch = None
    try:
        applied = client.run_realtime(
            duration,
            on_frame=lambda tr: recorder.unity_pose(
                unity_of.get(tr.topic, tr.topic),
                tr.unity_t_ns,
                tr.position,
                tr.orientation,
                tr.applied_stamp_ns,
            ),
        )
    except ProtocolMismatchError as exc:
        mismatch, applied = exc, []
    finally:
        writer.add_metadata("uwval.bridge_unity", _run_metadata(client, f"{host}:{port}"))
        recorder.close()
    if mismatch is not None:
        # nothing was recorded: an empty log left behind would read as a recording
        output.unlink(missing_ok=True)
        raise BridgeError(f"{mismatch}; no log written")
    _say_how_it_went(client, len(applied), output, f"{host}:{port}")


def _run_metadata(client: UnityClient, endpoint: str) -> dict[str, str]:
    """The ``uwval.bridge_unity`` metadata of a ``bridge unity`` recording."""
    from uwval.bridge import protocol as wire
    from uwval.bridge.unity_client import epoch_minus_monotonic_ns

    conn = client.connection
    return {
        "endpoint": endpoint,
        "protocol": conn.protocol if conn.connects else "",
        "endpoint_version": conn.server_version,
        "connections": str(conn.connects),
        "received": str(client.received),
        "endpoint_errors": str(conn.message_counts[wire.ERROR]),
        "endpoint_warnings": str(conn.message_counts[wire.WARN]),
        "epoch_minus_monotonic_ns_at_end": str(epoch_minus_monotonic_ns()),
    }


def _say_how_it_went(client: UnityClient, applied: int, output: Path, endpoint: str) -> None:
    """Print what ``bridge unity`` recorded; a clean error when it never connected, exit
    status 1 when the endpoint sent ``__error``."""
    from uwval.bridge import protocol as wire

    conn = client.connection
    counts = conn.message_counts
    console.print(
        f"[green]wrote[/] {output}: {applied} transforms, "
        f"{client.received} messages received ({conn.protocol}), {conn.connects} "
        f"connection(s); endpoint sent {counts[wire.ERROR]} error(s), "
        f"{counts[wire.WARN]} warning(s), {counts[wire.LOG]} log(s)"
    )
    if conn.connects == 0:
        why = f": {client.last_error}" if client.last_error else ""
        raise BridgeError(
            f"never connected to an endpoint at {endpoint}{why} "
            f"({output} holds no Unity transforms)"
        )
    if counts[wire.ERROR]:
        console.print(
            f"[red]error:[/] the endpoint sent {counts[wire.ERROR]} __error message(s) "
            "(shown above); exit status 1"
        )
        raise typer.Exit(1)


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
