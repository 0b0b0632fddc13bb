"""``uwval simulate``: one run, or a whole factorial experiment, into logs.

One run: ``uwval simulate --force 10,0,0 --duration 20 -o run.mcap``.
An experiment: ``uwval simulate data/experiments/default.toml -o DIR`` writes one log per run
under ``DIR/runs/`` and ``DIR/manifest.json`` (runs, factor levels, bridge statistics).
Into a running ROS-TCP endpoint (a real ROS graph): ``uwval simulate --endpoint HOST:PORT``
publishes the run's poses there in real time and runs the Unity-like client through it.
"""

from __future__ import annotations

import json
import threading
import time
from dataclasses import replace
from pathlib import Path
from typing import Annotated, Any

import typer
from rich.console import Console

from uwval.bridge.options import REAL_UNITY
from uwval.cli import app
from uwval.cli.pipeline import (
    FORMAT_SUFFIX,
    RunJob,
    SessionOptions,
    batch_physics,
    log_path_for,
    run_one,
)
from uwval.errors import ConfigError, UwvalError
from uwval.executors import run_tasks

console = Console()


def parse_vector(text: str, what: str) -> tuple[float, float, float]:
    """``"10,0,0"`` -> (10.0, 0.0, 0.0); a single number means the first axis."""
    try:
        parts = [float(p) for p in text.replace(" ", "").split(",") if p != ""]
    except ValueError:
        raise ConfigError(f"--{what}: expected three numbers like 10,0,0, got {text!r}") from None
    if len(parts) == 1:
        parts += [0.0, 0.0]
    if len(parts) != 3:
        raise ConfigError(f"--{what}: expected three numbers like 10,0,0, got {text!r}")
    return parts[0], parts[1], parts[2]


def factor_level(vec: tuple[float, float, float]) -> float:
    """One number for a run's force/torque/current factor (log metadata, results tables).

    The component when the vector lies on one axis (``10,0,0`` -> 10, ``0,0,-1`` -> -1, so
    the usual one-axis runs keep their sign), otherwise its Euclidean norm.
    """
    nonzero = [v for v in vec if v != 0.0]
    if len(nonzero) <= 1:
        return nonzero[0] if nonzero else 0.0
    return float(sum(v * v for v in vec) ** 0.5)


def check_output_suffix(output: Path, log_format: str) -> None:
    """Refuse a log name whose suffix says another format (``--format rosbag1 -o x.mcap``):
    readers pick the format by suffix, so such a log could not be compared."""
    known = {".mcap": "mcap", ".bag": "rosbag1"}
    said = known.get(output.suffix.lower())
    if said is not None and FORMAT_SUFFIX[log_format] != output.suffix.lower():
        raise ConfigError(
            f"-o {output}: the suffix {output.suffix} means {said}, but --format "
            f"is {log_format}; name the log {output.with_suffix('')}"
            f"{FORMAT_SUFFIX[log_format]} or change --format"
        )


def run_experiment(
    experiment: Path,
    out_dir: Path,
    session: SessionOptions,
    *,
    executor: str = "local",
    workers: int | None = None,
    scheduler: str | None = None,
    progress: bool = True,
    batched: bool = False,
) -> dict[str, Any]:
    """Run every run of an experiment file; write and return the manifest.

    ``batched``: step all runs' physics together in one vectorised state in this process
    first (fast for large sweeps of short runs); the bridge sessions then run on the executor.
    """
    from uwval.simulator import load_experiment

    exp = load_experiment(experiment)
    if exp.unity:  # the experiment's [unity] table decides for its runs
        try:
            session = replace(session, **exp.unity)
        except UwvalError as exc:
            raise ConfigError(f"{experiment}: unity: {exc}") from None
    specs = exp.runs()
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ConfigError(
            f"{out_dir}: cannot create the output directory: {exc.strerror or exc}"
        ) from None
    sims = batch_physics(specs, progress) if batched else [None] * len(specs)
    jobs = [
        RunJob(spec, str(log_path_for(out_dir, spec.name, session.log_format)), session, sim)
        for spec, sim in zip(specs, sims, strict=True)
    ]
    t0 = time.perf_counter()
    outcomes = run_tasks(
        run_one,
        jobs,
        [s.name for s in specs],
        executor=executor,
        workers=workers,
        scheduler=scheduler,
        progress=progress,
        description=f"simulate {len(specs)} runs",
    )
    runs = []
    for o in outcomes:
        if o.ok and o.value is not None:
            rec = dict(o.value)
            rec["log"] = str(Path(rec["log"]).relative_to(out_dir))
            runs.append(rec)
    failed = [
        {"name": o.key, "error": o.error, "attempts": o.attempts} for o in outcomes if not o.ok
    ]
    manifest = {
        "uwval_manifest": 1,
        "experiment": {"path": str(experiment), **_describe_experiment(exp)},
        "executor": executor,
        "wall_time_s": round(time.perf_counter() - t0, 3),
        "runs": runs,
        "failed": failed,
    }
    (out_dir / "manifest.json").write_text(json.dumps(manifest, indent=2))
    return manifest


def _describe_experiment(exp: Any) -> dict[str, Any]:
    if hasattr(exp, "describe"):
        return dict(exp.describe())
    return {"name": getattr(exp, "name", "")}


@app.command()
def simulate(
    experiment: Annotated[
        Path | None, typer.Argument(help="Experiment TOML (factors x levels); omit for one run.")
    ] = None,
    output: Annotated[
        Path, typer.Option("-o", "--output", help="Log file (one run) or directory (experiment).")
    ] = Path("run.mcap"),
    force: Annotated[
        str, typer.Option(help="Force FX,FY,FZ in N (body FLU; see --wrench-frame).")
    ] = "0,0,0",
    torque: Annotated[
        str, typer.Option(help="Torque TX,TY,TZ in N m (body FLU; see --wrench-frame).")
    ] = "0,0,0",
    current: Annotated[
        str, typer.Option(help="Water current CX,CY,CZ in m/s (world ENU).")
    ] = "0,0,0",
    duration: Annotated[float, typer.Option(help="Run length in seconds of sim time.")] = 20.0,
    vehicle: Annotated[
        str, typer.Option(help="Preset name, MODEL.sdf or VEHICLE.toml.")
    ] = "tethys",
    added_mass: Annotated[
        str,
        typer.Option(
            help="One run: explicit (as Gazebo: lagged, diverges when |X_dot| >= m, e.g. the "
            "published bluerov2_heavy) or implicit (added mass in the mass matrix).",
        ),
    ] = "explicit",
    legacy_coriolis: Annotated[
        bool,
        typer.Option(help="One run: gz-sim 8.0-8.11 / 9.x / 10.0-10.1 Coriolis entries."),
    ] = False,
    legacy_gz8: Annotated[
        bool,
        typer.Option(
            "--legacy-gz8",
            help="One run: gz-sim 8.0-8.11's Hydrodynamics: its Coriolis entries and its zero "
            "initial prevState (added-mass kick with a current); not the int abs() (see "
            "--int-abs-damping).",
        ),
    ] = False,
    int_abs_damping: Annotated[
        bool,
        typer.Option(
            "--int-abs-damping",
            help="One run: truncate |v| in the quadratic damping to an integer (C's int "
            "abs()). An emulation only: gz-sim 8.0-8.11's Hydrodynamics.cc includes Eigen and "
            "protobuf headers that bring the double overload, so real builds very likely never "
            "truncated.",
        ),
    ] = False,
    wrench_frame: Annotated[
        str,
        typer.Option(
            help="One run: frame of --force/--torque: body (FLU, moves with the vehicle) or "
            "world (ENU, as gz-sim's ApplyLinkWrench takes it).",
        ),
    ] = "body",
    log_format: Annotated[
        str, typer.Option("--format", help="mcap, rosbag2 (sqlite3), rosbag2-mcap or rosbag1.")
    ] = "mcap",
    publish_rate: Annotated[float, typer.Option(help="Gazebo pose publish rate, Hz.")] = 50.0,
    frame_rate: Annotated[
        float, typer.Option(help="Unity render rate (vsync: display refresh), Hz.")
    ] = float(REAL_UNITY["frame_rate"]),  # type: ignore[arg-type]
    unity_map: Annotated[
        str,
        typer.Option(
            help="ROS-TCP-Connector map: unity-flu, unity-enu (compass north) or "
            "unity-enu-south|west (its GeometryCompass setting; east = unity-flu); a scene "
            "declaring FRD / NED / RUF: unity-frd (= unity-ned), unity-ned-east|south|west, "
            "unity-ruf.",
        ),
    ] = "unity-flu",
    latency: Annotated[float, typer.Option(help="Injected one-way latency, s.")] = 0.0,
    jitter: Annotated[float, typer.Option(help="Render-frame jitter (std), s.")] = 0.0,
    drop: Annotated[float, typer.Option(help="Probability of dropping a pose message.")] = 0.0,
    unity_clock_offset: Annotated[
        float, typer.Option(help="Unity clock minus sim clock, s.")
    ] = 0.0,
    unity_clock_drift: Annotated[
        float, typer.Option(help="Unity clock rate error, ppm (a quartz clock: 10-50).")
    ] = float(REAL_UNITY["clock_drift_ppm"]),  # type: ignore[arg-type]
    transport: Annotated[
        str,
        typer.Option(
            help="Link timing: real-endpoint (ROS-TCP-Endpoint 0.7.0: Nagle + delayed ACK, "
            "p50 0.6 ms, p99 ~21 ms at 50 Hz), nodelay (TCP_NODELAY, p99 ~0.25 ms) or ideal.",
        ),
    ] = str(REAL_UNITY["transport"]),
    frame_model: Annotated[
        str,
        typer.Option(
            help="Unity frame times: vsync (--frame-rate display, missed vsyncs with "
            "--stall-prob), fixed, or trace (--frame-trace).",
        ),
    ] = str(REAL_UNITY["frame_model"]),
    stall_prob: Annotated[
        float, typer.Option(help="vsync: probability that a frame misses its vsync.")
    ] = float(REAL_UNITY["stall_prob"]),  # type: ignore[arg-type]
    frame_trace: Annotated[
        Path | None,
        typer.Option(help="trace: file of measured frame durations (s), one per line."),
    ] = None,
    float32: Annotated[
        bool,
        typer.Option(
            "--float32/--no-float32", help="Store poses as Unity's Transform does (float32)."
        ),
    ] = bool(REAL_UNITY["float32"]),
    seed: Annotated[int, typer.Option(help="Seed for jitter/drops (and the experiment).")] = 0,
    as_json: Annotated[
        bool,
        typer.Option(
            "--json",
            help="One run: print its record (bridge statistics, sim info, options) as JSON.",
        ),
    ] = False,
    realtime: Annotated[
        bool, typer.Option(help="Pace the virtual clock to the wall clock.")
    ] = False,
    executor: Annotated[str, typer.Option(help="local (process pool), dask or inline.")] = "local",
    workers: Annotated[
        int | None, typer.Option(help="Worker processes (default: all cores).")
    ] = None,
    scheduler: Annotated[
        str | None, typer.Option(help="Dask scheduler address (tcp://...).")
    ] = None,
    batch_physics_: Annotated[
        bool,
        typer.Option(
            "--batch-physics",
            help="Experiment: step all runs' physics together in one "
            "vectorised state first (large sweeps of short runs).",
        ),
    ] = False,
    endpoint: Annotated[
        str | None,
        typer.Option(
            help="One run: publish the simulated Gazebo poses INTO a running ROS-TCP "
            "endpoint at HOST:PORT (Unity's ROS-TCP-Endpoint or uwval bridge serve) as a ROS "
            "publisher, in real time; -o records the Gazebo side.",
        ),
    ] = None,
    endpoint_namespace: Annotated[
        str,
        typer.Option(
            help="With --endpoint: ROS namespace of the topics (e.g. /gazebo gives "
            "/gazebo/model_rov_pose); default relative names model_rov_pose, gui_camera_pose.",
        ),
    ] = "",
    endpoint_wait: Annotated[
        float,
        typer.Option(
            help="With --endpoint: seconds between registering the topics and the first "
            "pose (ROS 1 drops what is published before a subscriber has connected).",
        ),
    ] = 1.0,
    endpoint_unity: Annotated[
        bool,
        typer.Option(
            "--endpoint-unity/--no-endpoint-unity",
            help="With --endpoint: also run the Unity-like client through the same endpoint "
            "and record its side (the whole loop).",
        ),
    ] = True,
) -> None:
    """Simulate, bridge over TCP and record paired Gazebo/Unity pose logs."""
    if endpoint is not None and experiment is not None:
        raise ConfigError("--endpoint publishes one run; it does not take an experiment file")
    if endpoint is not None:
        # through a real endpoint the link is real: injected faults would be silently unused
        injected = [
            flag
            for flag, value in (("--latency", latency), ("--jitter", jitter), ("--drop", drop))
            if value
        ]
        if injected:
            raise ConfigError(
                f"{', '.join(injected)}: injected faults apply to uwval's own loopback link; "
                "with --endpoint the link to the real endpoint is measured as it is"
            )
    session = SessionOptions(
        unity_map=unity_map,
        frame_rate=frame_rate,
        latency_s=latency,
        jitter_s=jitter,
        drop_prob=drop,
        unity_clock_offset_s=unity_clock_offset,
        realtime=realtime,
        log_format=log_format,
        transport=transport,
        frame_model=frame_model,
        stall_prob=stall_prob,
        frame_trace=str(frame_trace) if frame_trace is not None else None,
        float32=float32,
        clock_drift_ppm=unity_clock_drift,
    )
    if experiment is not None:
        if output.suffix in (".mcap", ".bag", ".db3"):
            output = output.with_suffix("")
        manifest = run_experiment(
            experiment,
            output,
            session,
            executor=executor,
            workers=workers,
            scheduler=scheduler,
            batched=batch_physics_,
        )
        console.print(
            f"[green]{len(manifest['runs'])} runs[/] written to {output}/runs, manifest "
            f"{output / 'manifest.json'} ({manifest['wall_time_s']:.1f} s)"
        )
        for f in manifest["failed"]:
            console.print(f"[red]run {f['name']} failed:[/] {f['error']}")
        if manifest["failed"]:
            raise typer.Exit(1)
        return
    from uwval.simulator import RunSpec, constant_inputs, load_vehicle

    if not 0 < duration < float("inf"):
        raise ConfigError(f"--duration must be a positive number of seconds, got {duration}")
    if added_mass not in ("explicit", "implicit"):
        raise ConfigError(f"--added-mass {added_mass!r}: choose explicit or implicit")
    if wrench_frame not in ("body", "world"):
        raise ConfigError(f"--wrench-frame {wrench_frame!r}: choose body or world")
    check_output_suffix(output, log_format)
    f, tq, c = (
        parse_vector(force, "force"),
        parse_vector(torque, "torque"),
        parse_vector(current, "current"),
    )
    from uwval.simulator import AddedMass, CoriolisEntries, GazeboModel

    _model = GazeboModel(
        added_mass=AddedMass(added_mass),
        coriolis=CoriolisEntries.LEGACY if legacy_coriolis else CoriolisEntries.FIXED,
        int_abs_damping=int_abs_damping,
    )
    if legacy_gz8:
        _model = _model.as_legacy_gz8()
    spec = RunSpec(
        name=output.stem,
        factors={"force": factor_level(f), "torque": factor_level(tq), "current": factor_level(c)},
        vehicle=load_vehicle(vehicle),
        inputs=constant_inputs(f, tq, c, wrench_frame=wrench_frame),
        duration_s=duration,
        seed=seed,
        publish_rate=publish_rate,
        model=_model,
    )
    if endpoint is not None:
        _publish_to_endpoint(
            spec,
            output,
            log_format,
            endpoint,
            endpoint_namespace,
            endpoint_wait,
            as_json,
            session,
            endpoint_unity,
        )
        return
    t0 = time.perf_counter()
    with console.status(f"simulating {duration:g} s and bridging over TCP..."):
        record = run_one(RunJob(spec, str(output), session))
    b = record["bridge"]
    if as_json:
        typer.echo(json.dumps(record, indent=2))
        return
    console.print(
        f"[green]wrote[/] {output} in {time.perf_counter() - t0:.2f} s: "
        f"{b.get('sent', 0)} poses sent, {b.get('received', 0)} received, "
        f"{b.get('applied', 0)} applied in {b.get('frames', 0)} Unity frames, "
        f"{b.get('dropped', 0) + b.get('server_dropped', 0)} dropped; render lag "
        + (
            f"{1e3 * b['render_lag_mean_s']:.1f} ms mean"
            if b.get("render_lag_mean_s") is not None
            else "n/a (nothing rendered)"
        )
    )


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


def _publish_to_endpoint(
    spec: Any,
    output: Path,
    log_format: str,
    endpoint: str,
    namespace: str,
    wait: float,
    as_json: bool,
    session: SessionOptions,
    unity: bool,
) -> None:
    """``simulate --endpoint``: stream the run's ticks into a running endpoint, in real time,
    and (``unity``) run the Unity-like client through the same endpoint, both sides recorded.

    The Unity client's clock is the sim clock (monotonic time since the first tick was due,
    plus ``--unity-clock-offset``), as in a virtual ``uwval simulate`` run, so the log compares
    as it is.
    """
    from uwval.bridge.gazebo import EndpointPublisher, publish_ticks_realtime
    from uwval.bridge.recorder import UNITY_PREFIX, BridgeRecorder, log_topic
    from uwval.bridge.unity_client import UnityClient
    from uwval.cli.pipeline import _ticks_of
    from uwval.io import open_writer
    from uwval.io.atomic import atomic_output
    from uwval.simulator import SimulationStream

    host, port = parse_endpoint(endpoint)
    topics = endpoint_topics(namespace)
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
                    _ticks_of(stream), publisher, writer=writer, start_at_ns=start_ns
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
