"""``uwval simulate``: one run, or a whole factorial experiment, into logs.

One run: ``uwval simulate --force 10,0,0 --duration 20 -o run.mcap``.
An experiment: ``uwval simulate default -o DIR`` (an embedded experiment by name, or a TOML
file) writes one log per run under ``DIR/runs/`` and ``DIR/manifest.json``.
Into a running ROS-TCP endpoint (a real ROS graph): ``uwval simulate --endpoint HOST:PORT``.

The options are declared once, in :data:`SIMULATE_OPTIONS` (typer builds the command from
it); the command builds one :class:`~uwval.bridge.experiment.SimulateOptions` and calls
:func:`~uwval.bridge.experiment.run_experiment` or :func:`~uwval.bridge.experiment.run_single`.
"""

from __future__ import annotations

import json
import time
from enum import Enum
from pathlib import Path
from typing import Any, TypeVar

import typer
from rich.console import Console

from uwval.batch.executors import Executor
from uwval.bridge.experiment import (
    SimulateOptions,
    SingleRun,
    WrenchFrame,
    run_experiment,
    run_single,
)
from uwval.bridge.options import REAL_UNITY, SessionOptions
from uwval.cli import app
from uwval.cli.declare import Arg, Opt, declare_signature, opt
from uwval.cli.shared_options import EXECUTOR, JSON, SCHEDULER, WORKERS
from uwval.cli.simulate_endpoint import EndpointTarget, publish_to_endpoint
from uwval.errors import ConfigError
from uwval.simulator.model import AddedMass, CaSign, CoriolisEntries, GazeboModel

console = Console()
E = TypeVar("E", bound=Enum)


_o = opt
_ONE = "One run: "
#: Every option of ``uwval simulate``, in ``--help`` order.
SIMULATE_OPTIONS: tuple[Opt, ...] = (
    _o("output", Path, Path("run.mcap"), "Log file (one run) or directory (experiment).",
       "-o", "--output"),
    _o("force", str, "0,0,0", "Force FX,FY,FZ in N (body FLU; see --wrench-frame)."),
    _o("torque", str, "0,0,0", "Torque TX,TY,TZ in N m (body FLU; see --wrench-frame)."),
    _o("current", str, "0,0,0", "Water current CX,CY,CZ in m/s (world ENU)."),
    _o("duration", float, 20.0, "Run length in seconds of sim time."),
    _o("vehicle", str, "tethys", "Preset name, MODEL.sdf or VEHICLE.toml."),
    _o("added_mass", str, "explicit", _ONE + "explicit (the Hydrodynamics plugin's backward "
       "difference: diverges when |X_dot| >= m, e.g. the published bluerov2_heavy) or implicit "
       "(added mass in the mass matrix, as gz-physics' DART applies <fluid_added_mass>)."),
    _o("ca_sign", str, "gazebo", _ONE + "sign of the added-mass Coriolis wrench: gazebo (+C_A, "
       "the Hydrodynamics plugin) or fossen (-C_A, Kirchhoff's; a rigid body whose inertia "
       "holds the added mass)."),
    _o("legacy_coriolis", bool, False, _ONE + "gz-sim 8.0-8.11 / 9.x / 10.0-10.1 Coriolis "
       "entries."),
    _o("legacy_gz8", bool, False, _ONE + "gz-sim 8.0-8.11's Hydrodynamics: its Coriolis entries "
       "and its zero initial prevState (added-mass kick with a current); not the int abs() "
       "(see --int-abs-damping).", "--legacy-gz8"),
    _o("int_abs_damping", bool, False, _ONE + "truncate |v| in the quadratic damping to an "
       "integer (C's int abs()). An emulation only: gz-sim 8.0-8.11's Hydrodynamics.cc includes "
       "Eigen and protobuf headers that bring the double overload, so real builds very likely "
       "never truncated.", "--int-abs-damping"),
    _o("wrench_frame", str, "body", _ONE + "frame of --force/--torque: body (FLU, moves with "
       "the vehicle) or world (ENU, as gz-sim's ApplyLinkWrench takes it)."),
    _o("log_format", str, "mcap", "mcap, rosbag2 (sqlite3), rosbag2-mcap or rosbag1.",
       "--format"),
    _o("publish_rate", float, 50.0, "Gazebo pose publish rate, Hz."),
    _o("frame_rate", float, float(REAL_UNITY["frame_rate"]),  # type: ignore[arg-type]
       "Unity render rate (vsync: display refresh), Hz."),
    _o("unity_map", str, "unity-flu", "ROS-TCP-Connector map: unity-flu, unity-enu (compass "
       "north) or unity-enu-south|west (its GeometryCompass setting; east = unity-flu); a scene "
       "declaring FRD / NED / RUF: unity-frd (= unity-ned), unity-ned-east|south|west, "
       "unity-ruf."),
    _o("latency", float, 0.0, "Injected one-way latency, s."),
    _o("jitter", float, 0.0, "Render-frame jitter (std), s."),
    _o("drop", float, 0.0, "Probability of dropping a pose message."),
    _o("unity_clock_offset", float, 0.0, "Unity clock minus sim clock, s."),
    _o("unity_clock_drift", float, float(REAL_UNITY["clock_drift_ppm"]),  # type: ignore[arg-type]
       "Unity clock rate error, ppm (a quartz clock: 10-50)."),
    _o("transport", str, str(REAL_UNITY["transport"]), "Link timing: real-endpoint "
       "(ROS-TCP-Endpoint 0.7.0: Nagle + delayed ACK, p50 0.6 ms, p99 ~21 ms at 50 Hz), "
       "nodelay (TCP_NODELAY, p99 ~0.25 ms) or ideal."),
    _o("frame_model", str, str(REAL_UNITY["frame_model"]), "Unity frame times: vsync "
       "(--frame-rate display, missed vsyncs with --stall-prob), fixed, or trace "
       "(--frame-trace)."),
    _o("stall_prob", float, float(REAL_UNITY["stall_prob"]),  # type: ignore[arg-type]
       "vsync: probability that a frame misses its vsync."),
    _o("frame_trace", Path, None, "trace: file of measured frame durations (s), one per line."),
    _o("float32", bool, bool(REAL_UNITY["float32"]),
       "Store poses as Unity's Transform does (float32).", "--float32/--no-float32"),
    _o("seed", int, 0, "Seed for jitter/drops (and the experiment)."),
    JSON,
    _o("realtime", bool, False, "Pace the virtual clock to the wall clock."),
    EXECUTOR,
    WORKERS,
    SCHEDULER,
    _o("batch_physics", bool, False, "Experiment: step all runs' physics together in one "
       "vectorised state first (large sweeps of short runs).", "--batch-physics"),
    _o("endpoint", str, None, _ONE + "publish the simulated Gazebo poses INTO a running "
       "ROS-TCP endpoint at HOST:PORT (Unity's ROS-TCP-Endpoint or uwval bridge serve) as a "
       "ROS publisher, in real time; -o records the Gazebo side."),
    _o("endpoint_namespace", str, "", "With --endpoint: ROS namespace of the topics (e.g. "
       "/gazebo gives /gazebo/model_rov_pose); default relative names model_rov_pose, "
       "gui_camera_pose."),
    _o("endpoint_wait", float, 1.0, "With --endpoint: seconds between registering the topics "
       "and the first pose (ROS 1 drops what is published before a subscriber has connected)."),
    _o("endpoint_unity", bool, True, "With --endpoint: also run the Unity-like client through "
       "the same endpoint and record its side (the whole loop).",
       "--endpoint-unity/--no-endpoint-unity"),
)  # fmt: skip


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


def _choice(value: str, enum: type[E], flag: str) -> E:
    """``value`` as a member of ``enum``, or a one-line error naming the flag and the choices."""
    try:
        return enum(value)
    except ValueError:
        names = [str(m.value) for m in enum]
        raise ConfigError(
            f"{flag} {value!r}: choose {', '.join(names[:-1])} or {names[-1]}"
        ) from None


def session_options(kw: dict[str, Any]) -> SessionOptions:
    """The bridge session of the command line's options (checked by SessionOptions)."""
    trace = kw["frame_trace"]
    return SessionOptions(
        unity_map=kw["unity_map"],
        frame_rate=kw["frame_rate"],
        latency_s=kw["latency"],
        jitter_s=kw["jitter"],
        drop_prob=kw["drop"],
        unity_clock_offset_s=kw["unity_clock_offset"],
        realtime=kw["realtime"],
        log_format=kw["log_format"],
        transport=kw["transport"],
        frame_model=kw["frame_model"],
        stall_prob=kw["stall_prob"],
        frame_trace=str(trace) if trace is not None else None,
        float32=kw["float32"],
        clock_drift_ppm=kw["unity_clock_drift"],
    )


def simulate_options(kw: dict[str, Any]) -> SimulateOptions:
    """One :class:`SimulateOptions` from the command line's keyword values."""
    model = GazeboModel(
        added_mass=_choice(kw["added_mass"], AddedMass, "--added-mass"),
        ca_sign=_choice(kw["ca_sign"], CaSign, "--ca-sign"),
        coriolis=CoriolisEntries.LEGACY if kw["legacy_coriolis"] else CoriolisEntries.FIXED,
        int_abs_damping=kw["int_abs_damping"],
    )
    run = SingleRun(
        force=parse_vector(kw["force"], "force"),
        torque=parse_vector(kw["torque"], "torque"),
        current=parse_vector(kw["current"], "current"),
        duration_s=kw["duration"],
        vehicle=kw["vehicle"],
        model=model.as_legacy_gz8() if kw["legacy_gz8"] else model,
        wrench_frame=_choice(kw["wrench_frame"], WrenchFrame, "--wrench-frame"),
        publish_rate=kw["publish_rate"],
        seed=kw["seed"],
    )
    return SimulateOptions(
        output=kw["output"],
        experiment=kw["experiment"],
        run=run,
        session=session_options(kw),
        executor=_choice(kw["executor"], Executor, "--executor"),
        workers=kw["workers"],
        scheduler=kw["scheduler"],
        batch_physics=kw["batch_physics"],
        progress=True,
    )


def _check_endpoint_use(kw: dict[str, Any]) -> None:
    """--endpoint publishes one run over a real link: no experiment, no injected faults."""
    if kw["experiment"] is not None:
        raise ConfigError("--endpoint publishes one run; it does not take an experiment file")
    # through a real endpoint the link is real: injected faults would be silently unused
    injected = [f for f in ("latency", "jitter", "drop") if kw[f]]
    if injected:
        raise ConfigError(
            f"{', '.join('--' + f for f in injected)}: injected faults apply to uwval's own "
            "loopback link; with --endpoint the link to the real endpoint is measured as it is"
        )


def simulate(**kw: Any) -> None:
    """Simulate, bridge over TCP and record paired Gazebo/Unity pose logs."""
    if kw["endpoint"] is not None:
        _check_endpoint_use(kw)
    options = simulate_options(kw)
    if options.experiment is not None:
        result = run_experiment(options)
        console.print(
            f"[green]{len(result.runs)} runs[/] written to {result.out_dir}/runs, manifest "
            f"{result.manifest_path} ({result.wall_time_s:.1f} s)"
        )
        for f in result.failed:
            console.print(f"[red]run {f['name']} failed:[/] {f['error']}")
        if not result.ok:
            raise typer.Exit(1)
        return
    if kw["endpoint"] is not None:
        target = EndpointTarget(
            kw["endpoint"], kw["endpoint_namespace"], kw["endpoint_wait"], kw["endpoint_unity"]
        )
        spec = options.run.spec(options.output.stem)
        publish_to_endpoint(spec, options.output, target, options.session, kw["as_json"])
        return
    t0 = time.perf_counter()
    with console.status(f"simulating {options.run.duration_s:g} s and bridging over TCP..."):
        record = run_single(options)
    if kw["as_json"]:
        typer.echo(json.dumps(record, indent=2))
        return
    _print_run(options.output, record, time.perf_counter() - t0)


def _print_run(output: Path, record: dict[str, Any], wall_s: float) -> None:
    """The one-run summary line: poses sent, received, applied, dropped; render lag."""
    b = record["bridge"]
    lag = b.get("render_lag_mean_s")
    console.print(
        f"[green]wrote[/] {output} in {wall_s:.2f} s: "
        f"{b.get('sent', 0)} poses sent, {b.get('received', 0)} received, "
        f"{b.get('applied', 0)} applied in {b.get('frames', 0)} Unity frames, "
        f"{b.get('dropped', 0) + b.get('server_dropped', 0)} dropped; render lag "
        + (f"{1e3 * lag:.1f} ms mean" if lag is not None else "n/a (nothing rendered)")
    )


#: The experiment argument of ``simulate`` (omitted: one run).
_EXPERIMENT = Arg(
    "experiment",
    str,
    "Experiment TOML file, or an embedded experiment's name (default, "
    "quick, bluerov2_sweep); omit for one run.",
    default=None,
    show_default=False,
)
declare_signature(simulate, (_EXPERIMENT, *SIMULATE_OPTIONS))
app.command(name="simulate")(simulate)
