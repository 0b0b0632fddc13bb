"""Run an experiment without the command line: simulator -> TCP bridge -> Unity-like client -> log.

The one place where the simulator and the bridge meet (DESIGN.md: the bridge may drive the
simulator; the simulator never imports the bridge). ``uwval simulate`` and ``uwval demo`` build
a :class:`SimulateOptions` and call :func:`run_experiment` (a factorial sweep, one log per
run and a manifest) or :func:`run_single` (one run, one log)::

    from uwval.bridge.experiment import SimulateOptions, run_experiment
    result = run_experiment(SimulateOptions(output=Path("out"), experiment="quick"))
    result.manifest_path  # out/manifest.json; logs in out/runs/

One run is one task, so a sweep runs on any executor of :mod:`uwval.batch.executors` (process
pool, inline or Dask) with identical logs.
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Iterator
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from uwval.batch.executors import Executor, run_tasks
from uwval.bridge.options import LOG_SUFFIX, SessionOptions
from uwval.compat import StrEnum
from uwval.errors import ConfigError, UwvalError
from uwval.resources import data_dir
from uwval.simulator.model import PLUGIN_ADDED_MASS, GazeboModel

if TYPE_CHECKING:
    from uwval.bridge.gazebo import Tick
    from uwval.simulator import RunSpec, SimResult, TickChunk

__all__ = [
    "FORMAT_SUFFIX",
    "ExperimentResult",
    "RunJob",
    "SimulateOptions",
    "SingleRun",
    "WrenchFrame",
    "batch_physics",
    "embedded_experiments",
    "ensure_parent_dir",
    "log_path_for",
    "resolve_experiment",
    "run_experiment",
    "run_one",
    "run_single",
    "ticks_of",
]

#: Log file suffix for each log format (the bridge's table).
FORMAT_SUFFIX = LOG_SUFFIX

Vec3 = tuple[float, float, float]


class WrenchFrame(StrEnum):
    """The frame a run's force and torque are given in."""

    BODY = "body"  # FLU, moves with the vehicle
    WORLD = "world"  # ENU, as gz-sim's ApplyLinkWrench takes it


@dataclass(frozen=True)
class SingleRun:
    """One run with constant inputs (``uwval simulate --force ...``).

    Attributes:
        force: N, in ``wrench_frame``. torque: N m, in ``wrench_frame``.
        current: m/s, world ENU.
        duration_s: s of sim time.
        vehicle: preset name, MODEL.sdf or VEHICLE.toml.
        model: which gz-sim configuration the physics reproduces.
        publish_rate: Gazebo's pose publish rate, Hz.
        seed: seed of the Unity side (link timing, frame stalls).
    """

    force: Vec3 = (0.0, 0.0, 0.0)
    torque: Vec3 = (0.0, 0.0, 0.0)
    current: Vec3 = (0.0, 0.0, 0.0)
    duration_s: float = 20.0
    vehicle: str = "tethys"
    model: GazeboModel = PLUGIN_ADDED_MASS
    wrench_frame: WrenchFrame = WrenchFrame.BODY
    publish_rate: float = 50.0
    seed: int = 0

    def spec(self, name: str) -> RunSpec:
        """The simulator's RunSpec of this run (factor levels: one number per input)."""
        from uwval.simulator import RunSpec, constant_inputs, load_vehicle

        if not (math.isfinite(self.duration_s) and self.duration_s > 0):
            raise ConfigError(
                f"--duration must be a positive number of seconds, got {self.duration_s}"
            )
        return RunSpec(
            name=name,
            factors={
                "force": factor_level(self.force),
                "torque": factor_level(self.torque),
                "current": factor_level(self.current),
            },
            vehicle=load_vehicle(self.vehicle),
            inputs=constant_inputs(
                self.force, self.torque, self.current, wrench_frame=WrenchFrame(self.wrench_frame)
            ),
            duration_s=self.duration_s,
            seed=self.seed,
            publish_rate=self.publish_rate,
            model=self.model,
        )


@dataclass(frozen=True)
class SimulateOptions:
    """What ``uwval simulate`` does, as one value.

    Attributes:
        output: the log (one run) or the output directory (an experiment).
        experiment: an experiment TOML file, or the name of an embedded one (``default``,
            ``quick``, ...: :func:`embedded_experiments`); None for one run (``run``).
        run: the one run's inputs and model (when ``experiment`` is None).
        session: the link, the Unity-like client and the recording (the experiment's
            ``[unity]`` table overrides it).
        executor: where the runs of an experiment go; workers, scheduler: its settings.
        batch_physics: step all runs' physics together in one vectorised state first.
        progress: show progress bars (rich) on the terminal.
    """

    output: Path
    experiment: str | Path | None = None
    run: SingleRun = field(default_factory=SingleRun)
    session: SessionOptions = field(default_factory=SessionOptions)
    executor: Executor = Executor.LOCAL
    workers: int | None = None
    scheduler: str | None = None
    batch_physics: bool = False
    progress: bool = False


@dataclass(frozen=True)
class ExperimentResult:
    """What :func:`run_experiment` wrote: the manifest (as written) and where it is.

    ``runs`` are the manifest's run records (log paths relative to ``out_dir``), ``failed``
    the runs that failed (name, error, attempts); ``wall_time_s`` the runs' wall time, s.
    """

    out_dir: Path
    manifest_path: Path
    manifest: dict[str, Any]
    runs: tuple[dict[str, Any], ...]
    failed: tuple[dict[str, Any], ...]
    wall_time_s: float

    @property
    def ok(self) -> bool:
        """Every run was written."""
        return not self.failed


@dataclass(frozen=True)
class RunJob:
    """One run to execute: the simulator's RunSpec, where to write, how to bridge."""

    spec: RunSpec
    log_path: str
    session: SessionOptions = field(default_factory=SessionOptions)
    sim: SimResult | None = None  # precomputed (batched physics), else streamed by run_one


def factor_level(vec: Vec3) -> float:
    """One number for a run's force/torque/current factor (log metadata, results tables).

    The component when the vector lies on one axis (``10,0,0`` -> 10, ``0,0,-1`` -> -1, so
    the usual one-axis runs keep their sign), otherwise its Euclidean norm.
    """
    nonzero = [v for v in vec if v != 0.0]
    if len(nonzero) <= 1:
        return nonzero[0] if nonzero else 0.0
    return float(sum(v * v for v in vec) ** 0.5)


def embedded_experiments() -> tuple[str, ...]:
    """Names of the experiments shipped with uwval (``uwval simulate NAME``)."""
    return tuple(sorted(p.stem for p in (data_dir() / "experiments").glob("*.toml")))


def resolve_experiment(ref: str | Path) -> Path:
    """The experiment file ``ref`` names: an existing path, else an embedded experiment's
    name (works from any folder after ``pip install``); a clear error otherwise."""
    path = Path(ref)
    if path.is_file():
        return path
    names = embedded_experiments()
    if str(ref) in names:
        return data_dir() / "experiments" / f"{ref}.toml"
    if path.exists():
        raise ConfigError(f"experiment {ref}: a directory, not an experiment TOML file")
    raise ConfigError(
        f"experiment file {ref} does not exist (embedded experiments: {', '.join(names)})"
    )


def run_experiment(options: SimulateOptions) -> ExperimentResult:
    """Run every run of ``options.experiment`` into ``options.output``/runs/; write and return
    the manifest (``options.output``/manifest.json).

    With ``batch_physics`` all runs' physics is stepped together in this process first (fast
    for large sweeps of short runs); the bridge sessions then run on the executor.
    """
    from uwval.simulator import load_experiment

    if options.experiment is None:
        raise ConfigError("run_experiment needs an experiment (a TOML file or an embedded name)")
    source = resolve_experiment(options.experiment)
    exp = load_experiment(source)
    session = options.session
    if exp.unity:  # the experiment's [unity] table decides for its runs
        try:
            session = replace(session, **exp.unity)
        except UwvalError as exc:
            raise ConfigError(f"{source}: unity: {exc}") from None
    out_dir = options.output
    if out_dir.suffix in (".mcap", ".bag", ".db3"):
        out_dir = out_dir.with_suffix("")
    specs = exp.runs()
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ConfigError(
            f"{out_dir}: cannot create the output directory: {exc.strerror or exc}"
        ) from None
    sims = batch_physics(specs, options.progress) if options.batch_physics else [None] * len(specs)
    jobs = [
        RunJob(spec, str(log_path_for(out_dir, spec.name, session.log_format)), session, sim)
        for spec, sim in zip(specs, sims, strict=True)
    ]
    t0 = time.perf_counter()
    outcomes = run_tasks(
        run_one,
        jobs,
        [s.name for s in specs],
        executor=options.executor,
        workers=options.workers,
        scheduler=options.scheduler,
        progress=options.progress,
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
    wall = round(time.perf_counter() - t0, 3)
    manifest = {
        "uwval_manifest": 1,
        "experiment": {"path": str(source), "name": exp.name, "model": exp.model.to_dict()},
        "executor": str(options.executor),
        "wall_time_s": wall,
        "runs": runs,
        "failed": failed,
    }
    manifest_path = out_dir / "manifest.json"
    text = json.dumps(manifest, indent=2)
    try:
        manifest_path.write_text(text)
    except OSError as exc:
        raise ConfigError(f"{manifest_path}: cannot write: {exc.strerror or exc}") from None
    written = json.loads(text)  # the manifest as a reader of the file sees it (lists, not tuples)
    return ExperimentResult(
        out_dir, manifest_path, written, tuple(written["runs"]), tuple(written["failed"]), wall
    )


def run_single(options: SimulateOptions) -> dict[str, Any]:
    """Simulate ``options.run`` into the log ``options.output``; return its record (the
    ``--json`` of ``uwval simulate``: name, log, factors, bridge statistics, sim info)."""
    check_output_suffix(options.output, options.session.log_format)
    spec = options.run.spec(options.output.stem)
    return run_one(RunJob(spec, str(options.output), options.session))


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


def batch_physics(specs: list[RunSpec], progress: bool = True) -> list[SimResult]:
    """Every run's physics stepped together, one vectorised state per group of runs that
    share duration, step, publish rate, model and wrench frame (``simulate_batch``).

    Returns the SimResults in the order of ``specs``; equal to per-run ``simulate`` to
    rounding. Used by ``uwval simulate EXPERIMENT --batch-physics``.
    """
    from uwval.simulator import simulate_batch

    groups: dict[tuple[Any, ...], list[int]] = {}
    for i, s in enumerate(specs):
        kw = s.simulate_kwargs()
        key = (
            s.duration_s,
            s.inputs.wrench_frame,
            *sorted((k, v) for k, v in kw.items() if k != "seed"),
        )
        groups.setdefault(key, []).append(i)
    out: list[Any] = [None] * len(specs)
    bar: Any = None
    if progress:
        from rich.progress import Progress

        bar = Progress(transient=True)
        bar.start()
        task = bar.add_task(f"physics of {len(specs)} runs (batched)", total=len(specs))
    try:
        for idx in groups.values():
            first = specs[idx[0]]
            kw = {k: v for k, v in first.simulate_kwargs().items() if k != "seed"}
            results = simulate_batch(
                [specs[i].vehicle for i in idx],
                [specs[i].inputs for i in idx],
                first.duration_s,
                **kw,
            )
            for i, r in zip(idx, results, strict=True):
                out[i] = r
            if bar is not None:
                bar.advance(task, len(idx))
    finally:
        if bar is not None:
            bar.stop()
    return out


def log_path_for(out_dir: Path, name: str, log_format: str) -> Path:
    """Where a run's log goes inside an experiment directory."""
    if log_format not in FORMAT_SUFFIX:
        raise ConfigError(
            f"unknown log format {log_format!r}; choose one of {', '.join(FORMAT_SUFFIX)}"
        )
    return out_dir / "runs" / f"{name}{FORMAT_SUFFIX[log_format]}"


def ensure_parent_dir(path: Path) -> None:
    """Create ``path``'s directory, or raise a ConfigError naming it (no traceback)."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ConfigError(
            f"{path}: cannot create its directory {path.parent}: {exc.strerror or exc}"
        ) from None


def run_one(job: RunJob) -> dict[str, Any]:
    """Simulate one run, stream it through the bridge, record both sides; return its record.

    Without a precomputed ``job.sim`` the physics is streamed: chunks of publish ticks go
    to the bridge as they are stepped (:class:`uwval.simulator.SimulationStream`), so memory
    stays bounded however long the run. Module-level so that process pools and Dask
    workers can run it.
    """
    from uwval.bridge.recorder import open_log_writer
    from uwval.bridge.session import BridgeSession, ticks_from_streams
    from uwval.io.atomic import atomic_output
    from uwval.simulator import SimulationStream

    spec = job.spec
    opts = job.session
    path = Path(job.log_path)
    ensure_parent_dir(path)
    if job.sim is not None:
        info = job.sim.info
        ticks: Iterator[Tick] = ticks_from_streams(job.sim.vehicle, job.sim.camera)
    else:
        stream = SimulationStream(
            spec.vehicle, spec.inputs, spec.duration_s, **spec.simulate_kwargs()
        )
        info = stream.info
        ticks = ticks_of(stream)
    metadata = {
        "run": spec.name,
        "factors": json.dumps(spec.factors),
        "unity_map": opts.unity_map,
        "seed": str(spec.seed),
        "vehicle": str(info.get("vehicle", "")),
    }
    # Written under a temporary name and renamed when complete: a reader never sees half a
    # log, two runs never write one file, a failed run leaves <stem>.partial<suffix>.
    with (
        atomic_output(path) as tmp,
        open_log_writer(tmp, format=opts.log_format, metadata=metadata) as writer,
    ):
        stats = BridgeSession(writer, opts, seed=spec.seed).run(ticks)
    return {
        "name": spec.name,
        "log": str(path),
        "factors": dict(spec.factors),
        "seed": int(spec.seed),
        "duration_s": float(spec.duration_s),
        "bridge": _as_dict(stats),
        "sim": {k: v for k, v in info.items() if _jsonable(v)},
        "session": asdict(opts),
    }


def ticks_of(chunks: Iterator[TickChunk] | Any) -> Iterator[Tick]:
    """Publish ticks of streamed simulator chunks: the vehicle and its following camera
    (``model_rov_pose``, ``gui_camera_pose``, ENU/FLU), as ``ticks_from_streams`` makes them
    from whole streams."""
    from uwval.bridge.gazebo import CAMERA_TOPIC, VEHICLE_TOPIC

    for c in chunks:
        for k, t in enumerate(c.t.tolist()):
            yield (
                t,
                {
                    VEHICLE_TOPIC: (c.position[k], c.orientation[k]),
                    CAMERA_TOPIC: (c.camera_position[k], c.camera_orientation[k]),
                },
            )


def _as_dict(obj: Any) -> dict[str, Any]:
    if hasattr(obj, "as_dict"):
        return dict(obj.as_dict())
    if hasattr(obj, "__dataclass_fields__"):
        return {k: v for k, v in asdict(obj).items() if _jsonable(v)}
    return dict(obj)


def _jsonable(v: Any) -> bool:
    try:
        json.dumps(v)
    except TypeError:
        return False
    return True
