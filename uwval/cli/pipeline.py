"""The live pipeline of ``uwval simulate``: simulator -> TCP bridge -> Unity-like client -> log.

This is the one place where the simulator and the bridge meet (the CLI wires areas together;
the areas never import each other). One run is one task, so a factorial sweep runs on any
executor of :mod:`uwval.executors` (process pool or Dask) with identical logs.
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from uwval.bridge.options import LOG_SUFFIX, SessionOptions
from uwval.errors import ConfigError

if TYPE_CHECKING:
    from uwval.bridge.gazebo import Tick
    from uwval.simulator import RunSpec, SimResult, TickChunk

__all__ = [
    "FORMAT_SUFFIX",
    "RunJob",
    "SessionOptions",
    "batch_physics",
    "ensure_parent_dir",
    "log_path_for",
    "run_one",
]

#: Log file suffix for each --format (the bridge's table).
FORMAT_SUFFIX = LOG_SUFFIX


@dataclass(frozen=True)
class RunJob:
    """One run to execute: the simulator's RunSpec, where to write, how to bridge."""

    spec: RunSpec
    log_path: str
    session: SessionOptions = field(default_factory=SessionOptions)
    sim: SimResult | None = None  # precomputed (batched physics), else streamed by run_one


def batch_physics(specs: list[RunSpec], progress: bool = True) -> list[SimResult]:
    """Every run's physics stepped together, one vectorised state per group of runs that
    share duration, step, publish rate, switches and wrench frame (``simulate_batch``).

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
    stream: SimulationStream | None = None
    if job.sim is not None:
        info = job.sim.info
        ticks: Iterator[Tick] = ticks_from_streams(job.sim.vehicle, job.sim.camera)
    else:
        stream = SimulationStream(
            spec.vehicle, spec.inputs, spec.duration_s, **spec.simulate_kwargs()
        )
        info = stream.info
        ticks = _ticks_of(stream)
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


def _ticks_of(chunks: Iterator[TickChunk] | Any) -> Iterator[Tick]:
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
