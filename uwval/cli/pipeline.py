"""The live pipeline of ``uwval simulate``: simulator -> TCP bridge -> Unity-like client -> log.

This is the one place where the simulator and the bridge meet (the CLI wires areas together;
the areas never import each other). One run is one task, so a factorial sweep runs on any
executor of :mod:`uwval.executors` (process pool or Dask) with identical logs.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from uwval.errors import ConfigError

#: Log file suffix for each --format.
FORMAT_SUFFIX = {
    "mcap": ".mcap",
    "rosbag2": "",
    "rosbag2-sqlite3": "",
    "rosbag2-mcap": "",
    "rosbag1": ".bag",
}


@dataclass(frozen=True)
class SessionOptions:
    """How the bridge and the Unity-like client behave in a run (seconds, Hz)."""

    unity_map: str = "unity-flu"
    frame_rate: float = 60.0
    latency_s: float = 0.0
    jitter_s: float = 0.0
    drop_prob: float = 0.0
    unity_clock_offset_s: float = 0.0
    realtime: bool = False
    protocol: str = "ROS2"
    log_format: str = "mcap"

    def __post_init__(self) -> None:
        """Check every option now, before any simulation runs (one clean error, not one
        failed run per experiment run). The bridge's own classes own the rules."""
        from uwval.bridge import protocol as wire
        from uwval.bridge.unity_client import FaultModel, RenderLoop

        if self.log_format not in FORMAT_SUFFIX:
            raise ConfigError(
                f"--format {self.log_format!r}: choose one of {', '.join(FORMAT_SUFFIX)}"
            )
        wire.check_protocol(self.protocol)
        FaultModel(latency_s=self.latency_s, drop_prob=self.drop_prob)
        RenderLoop(
            [],
            unity_map=self.unity_map,
            frame_rate=self.frame_rate,
            frame_jitter_s=self.jitter_s,
            clock_offset_s=self.unity_clock_offset_s,
        )


@dataclass(frozen=True)
class RunJob:
    """One run to execute: the simulator's RunSpec, where to write, how to bridge."""

    spec: Any  # simulator.RunSpec (kept Any: the core does not import the simulator)
    log_path: str
    session: SessionOptions = field(default_factory=SessionOptions)
    sim: Any = None  # a precomputed simulator.SimResult (batched physics), else None


def batch_physics(specs: list[Any], progress: bool = True) -> list[Any]:
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

    Module-level so that process pools and Dask workers can run it.
    """
    from uwval.bridge.session import run_session, ticks_from_streams
    from uwval.io import open_writer
    from uwval.simulator import simulate

    spec = job.spec
    opts = job.session
    sim = (
        job.sim
        if job.sim is not None
        else simulate(spec.vehicle, spec.inputs, spec.duration_s, **spec.simulate_kwargs())
    )
    path = Path(job.log_path)
    ensure_parent_dir(path)
    metadata = {
        "run": spec.name,
        "factors": json.dumps(spec.factors),
        "unity_map": opts.unity_map,
        "seed": str(spec.seed),
        "vehicle": str(sim.info.get("vehicle", "")),
    }
    with open_writer(path, format=opts.log_format, metadata=metadata) as writer:
        stats = run_session(
            ticks_from_streams(sim.vehicle, sim.camera),
            writer,
            unity_map=opts.unity_map,
            frame_rate=opts.frame_rate,
            latency_s=opts.latency_s,
            jitter_s=opts.jitter_s,
            drop_prob=opts.drop_prob,
            unity_clock_offset_s=opts.unity_clock_offset_s,
            seed=spec.seed,
            realtime=opts.realtime,
            protocol=opts.protocol,
        )
    return {
        "name": spec.name,
        "log": str(path),
        "factors": dict(spec.factors),
        "seed": int(spec.seed),
        "duration_s": float(spec.duration_s),
        "bridge": _as_dict(stats),
        "sim": {k: v for k, v in sim.info.items() if _jsonable(v)},
        "session": asdict(opts),
    }


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
