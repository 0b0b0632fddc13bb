"""``uwval simulate --endpoint HOST:PORT``: publish one run into a running ROS-TCP endpoint.

The run's Gazebo poses go to a real endpoint (Unity's ROS-TCP-Endpoint or ``uwval bridge
serve``) as a ROS publisher, in real time, and the Unity-like client runs through the same
endpoint; both sides are recorded into one log. Also the endpoint helpers ``uwval teleop``
shares (:func:`parse_endpoint`, :func:`endpoint_topics`).
"""

from __future__ import annotations

import json
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import typer
from rich.console import Console

from uwval.bridge.options import SessionOptions
from uwval.errors import ConfigError

console = Console()


@dataclass(frozen=True)
class EndpointTarget:
    """Where and how ``--endpoint`` publishes: HOST:PORT, the topics' ROS namespace, the
    seconds between registering the topics and the first pose, and whether the Unity-like
    client runs through the same endpoint."""

    endpoint: str
    namespace: str = ""
    wait_s: float = 1.0
    unity: bool = True


def parse_endpoint(text: str, option: str = "--endpoint") -> tuple[str, int]:
    """``"127.0.0.1:10000"`` -> ("127.0.0.1", 10000); a clean error names the option."""
    host, sep, port = text.rpartition(":")
    if not sep or not host or not port.isdigit() or not 0 < int(port) <= 65535:
        raise ConfigError(f"{option}: expected HOST:PORT with a port 1-65535, got {text!r}")
    return host.strip("[]"), int(port)


def endpoint_topics(namespace: str) -> dict[str, str]:
    """Tick name -> ROS topic under ``namespace`` ("" keeps the relative names)."""
    from uwval.bridge.options import DEFAULT_TOPICS

    ns = namespace.strip()
    if ns and (not ns.startswith("/") or "//" in ns or any(c.isspace() for c in ns)):
        raise ConfigError(
            f"--endpoint-namespace {namespace!r}: expected an absolute ROS namespace like /gazebo"
        )
    return {t: f"{ns.rstrip('/')}/{t}" if ns else t for t in DEFAULT_TOPICS}


class _LockedWriter:
    """A log writer shared by the publishing loop and the Unity-like client's thread."""

    def __init__(self, writer: Any) -> None:
        self._writer = writer
        self._lock = threading.Lock()

    def write_pose(self, *args: Any, **kwargs: Any) -> None:
        with self._lock:
            self._writer.write_pose(*args, **kwargs)

    def write_header(self, *args: Any, **kwargs: Any) -> None:
        with self._lock:
            self._writer.write_header(*args, **kwargs)

    def flush(self) -> None:
        flush = getattr(self._writer, "flush", None)
        if flush is not None:
            with self._lock:
                flush()

    def close(self) -> None:  # the publishing side's ``with`` closes the real writer
        pass


def publish_to_endpoint(
    spec: Any, output: Path, target: EndpointTarget, session: SessionOptions, as_json: bool
) -> None:
    """``simulate --endpoint``: stream the run's ticks into a running endpoint, in real time,
    and (``unity``) run the Unity-like client through the same endpoint, both sides recorded.

    The Unity client's clock is the sim clock (monotonic time since the first tick was due,
    plus ``--unity-clock-offset``), as in a virtual ``uwval simulate`` run, so the log compares
    as it is.
    """
    from uwval.bridge.experiment import ticks_of
    from uwval.bridge.gazebo import EndpointPublisher, publish_ticks_realtime
    from uwval.bridge.recorder import UNITY_PREFIX, BridgeRecorder, log_topic
    from uwval.bridge.unity_client import UnityClient
    from uwval.io import open_writer
    from uwval.io.atomic import atomic_output
    from uwval.simulator import SimulationStream

    host, port = parse_endpoint(target.endpoint)
    topics = endpoint_topics(target.namespace)
    wait, unity, log_format = target.wait_s, target.unity, session.log_format
    if not 0 <= wait < float("inf"):
        raise ConfigError(f"--endpoint-wait must be a finite number of seconds >= 0, got {wait}")
    errors: list[str] = []

    def on_message(kind: str, text: str) -> None:
        if kind == "__error":
            errors.append(text)
        console.print(f"endpoint {kind}: {text}", highlight=False, markup=False)

    # The publisher connects first: the real endpoint sends to its newest connection only.
    publisher = EndpointPublisher(host, port, topics=topics, on_message=on_message)
    stream = SimulationStream(spec.vehicle, spec.inputs, spec.duration_s, **spec.simulate_kwargs())
    start_ns = time.monotonic_ns() + round(wait * 1e9)
    client: UnityClient | None = None
    applied = 0
    t0 = time.perf_counter()
    try:
        # as every simulate log: a temporary name renamed when complete, a failed run kept as
        # <stem>.partial<suffix>, a second writer of the same target refused
        with (
            atomic_output(output) as tmp,
            open_writer(
                tmp,
                format=log_format,
                metadata={
                    "run": spec.name,
                    "endpoint": f"{host}:{port}",
                    "topics": json.dumps(topics),
                },
            ) as raw_writer,
        ):
            writer = _LockedWriter(raw_writer)
            thread = None
            stop = threading.Event()
            if unity:
                client = UnityClient(
                    host,
                    port,
                    topics=list(topics.values()),
                    unity_map=session.unity_map,
                    frame_rate=session.frame_rate,
                    protocol="auto",
                    clock="monotonic",
                    on_message=on_message,
                )
                client.scene.offset_ns += round(session.unity_clock_offset_s * 1e9) - start_ns
                recorder = BridgeRecorder(writer, unity_map=session.unity_map)
                unity_of = {t: log_topic(UNITY_PREFIX, name) for name, t in topics.items()}
                run_client = client

                def render() -> None:
                    nonlocal applied
                    applied = len(
                        run_client.run_realtime(
                            wait + spec.duration_s + 5,
                            on_frame=lambda tr: recorder.unity_pose(
                                unity_of.get(tr.topic, tr.topic),
                                tr.unity_t_ns,
                                tr.position,
                                tr.orientation,
                                tr.applied_stamp_ns,
                            ),
                            stop=stop,
                        )
                    )

                thread = threading.Thread(target=render, daemon=True)
                thread.start()
            try:
                sent = publish_ticks_realtime(
                    ticks_of(stream), publisher, writer=writer, start_at_ns=start_ns
                )
                time.sleep(0.3 if unity else 0.0)  # the last poses through the endpoint
                publisher.service()
            finally:
                stop.set()
                if thread is not None:
                    thread.join(10)
    finally:
        publisher.close()
    record: dict[str, Any] = {
        "endpoint": f"{host}:{port}",
        "protocol": publisher.protocol,
        "topics": topics,
        "ticks": sent,
        "poses": publisher.seq,
        "endpoint_errors": errors,
        "log": str(output),
        "wall_time_s": round(time.perf_counter() - t0, 3),
    }
    if client is not None:
        record["unity"] = {
            "received": client.received,
            "applied": applied,
            "connections": client.connection.connects,
        }
    if as_json:
        typer.echo(json.dumps(record, indent=2))
    else:
        console.print(
            f"[green]published[/] {sent} ticks ({publisher.seq} poses) into {host}:{port} "
            f"({publisher.protocol}) on {', '.join(topics.values())}"
            + (
                f"; the Unity-like client received {client.received} and applied {applied}"
                if client is not None
                else ""
            )
            + f"; log {output}"
        )
    if errors:
        console.print(f"[red]error:[/] the endpoint sent {len(errors)} __error message(s)")
        raise typer.Exit(1)
