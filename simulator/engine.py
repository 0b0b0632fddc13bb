"""Running the physics: one vehicle (:func:`simulate`, :class:`Simulator` for live stepping) or
many at once (:func:`simulate_batch`), publishing poses at a fixed rate on sim time.

Time is int64 nanoseconds of sim time. A run steps ``dt`` (default 1 ms) and publishes the
vehicle pose and a following camera's pose every ``1 / publish_rate`` (default 50 Hz, i.e.
every 20 steps), starting with the initial pose at t = 0, as gz-sim's pose publisher stamps
sim time. Inputs are sampled at the start of each step (gz systems' PreUpdate).

Published streams (world ENU, body FLU, quaternions x y z w):

* ``/gazebo/model_rov_pose``: the vehicle (its CoG);
* ``/gazebo/gui_camera_pose``: a camera at ``camera_offset`` (m) from the vehicle in the
  vehicle's yaw frame (x ahead, y left, z up; default 3 m behind, 1 m above), its x axis
  pointing at the vehicle (roll 0), like Gazebo's GUI camera following a model.

Size: one module on purpose: :class:`Simulator`, :func:`simulate`, :func:`simulate_batch` and
:class:`SimulationStream` share the input sampling, publish schedule and divergence checks.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from uwval.posestream import PoseStream
from uwval.rotations import quat_from_rpy
from uwval.simulator.dynamics import N_STATE, build_params, get_kernel, initial_state
from uwval.simulator.errors import DivergenceError, SimulationError
from uwval.simulator.inputs import Constant, InputProfile, constant_inputs
from uwval.simulator.model import PLUGIN_ADDED_MASS, GazeboModel
from uwval.simulator.vehicle import Vehicle

F64 = NDArray[np.float64]

VEHICLE_TOPIC = "/gazebo/model_rov_pose"
CAMERA_TOPIC = "/gazebo/gui_camera_pose"
DEFAULT_CAMERA_OFFSET = (-3.0, 0.0, 1.0)
#: A body speed beyond this (m/s or rad/s) is taken as numerical divergence.
DIVERGENCE_LIMIT = 1.0e4
#: Steps per input chunk: inputs are evaluated vectorised over this many step times at once.
CHUNK_STEPS = 2000


@dataclass(frozen=True)
class InitialState:
    """Where a run starts: position (m, world ENU), orientation (x y z w, body FLU -> world
    ENU) and body twist (u v w m/s, p q r rad/s, FLU)."""

    position: tuple[float, float, float] = (0.0, 0.0, 0.0)
    orientation: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 1.0)
    velocity: tuple[float, float, float, float, float, float] = (0.0,) * 6


AT_REST = InitialState()


@dataclass
class SimResult:
    """One run's output.

    Attributes:
        vehicle: vehicle poses at publish ticks (topic ``/gazebo/model_rov_pose``, ``enu``).
        camera: following camera poses (topic ``/gazebo/gui_camera_pose``, ``enu``).
        velocity: (N, 6) body twist (u, v, w m/s; p, q, r rad/s, FLU) at the publish ticks.
        info: vehicle name, dt, publish rate, options, steps, wall time, ``warnings``.
    """

    vehicle: PoseStream
    camera: PoseStream
    velocity: F64
    info: dict[str, Any] = field(default_factory=dict)

    @property
    def t(self) -> NDArray[np.int64]:
        """Publish stamps, int64 ns of sim time."""
        return self.vehicle.t


def camera_poses(
    position: F64, orientation: F64, offset: Sequence[float] = DEFAULT_CAMERA_OFFSET
) -> tuple[F64, F64]:
    """Camera positions and orientations for vehicle poses (vectorised, (N, 3) / (N, 4)).

    The camera sits at ``offset`` in the vehicle's yaw frame and looks at the vehicle."""
    pos = np.asarray(position, dtype=np.float64).reshape(-1, 3)
    q = np.asarray(orientation, dtype=np.float64).reshape(-1, 4)
    x, y, z, w = q[:, 0], q[:, 1], q[:, 2], q[:, 3]
    yaw = np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    c, s = np.cos(yaw), np.sin(yaw)
    ox, oy, oz = (float(v) for v in offset)
    cam = np.empty_like(pos)
    cam[:, 0] = pos[:, 0] + c * ox - s * oy
    cam[:, 1] = pos[:, 1] + s * ox + c * oy
    cam[:, 2] = pos[:, 2] + oz
    d = pos - cam
    horiz = np.hypot(d[:, 0], d[:, 1])
    cam_yaw = np.where(horiz > 1e-12, np.arctan2(d[:, 1], d[:, 0]), yaw)
    cam_pitch = np.arctan2(-d[:, 2], horiz)  # FLU: positive pitch tips x down
    rpy = np.stack([np.zeros_like(cam_yaw), cam_pitch, cam_yaw], axis=1)
    return cam, quat_from_rpy(rpy)


def _check_timing(dt: float, publish_rate: float) -> tuple[int, int]:
    if not (dt > 0 and math.isfinite(dt)):
        raise SimulationError(f"step dt must be > 0 s, got {dt}")
    if not (publish_rate > 0 and math.isfinite(publish_rate)):
        raise SimulationError(f"publish rate must be > 0 Hz, got {publish_rate}")
    dt_ns = round(dt * 1e9)
    period_ns = round(1e9 / publish_rate)
    if dt_ns <= 0 or period_ns % dt_ns:
        raise SimulationError(
            f"publish period {period_ns} ns (rate {publish_rate} Hz) is not a whole number "
            f"of steps of {dt_ns} ns"
        )
    return dt_ns, period_ns // dt_ns


def _warnings_for(vehicles: Sequence[Vehicle], implicit: bool) -> list[str]:
    out: list[str] = []
    if implicit:
        return out
    for v in vehicles:
        axes = v.explicit_added_mass_unstable_axes()
        if axes:
            out.append(
                f"explicit added mass unstable for {v.name}: {'; '.join(axes)}. Gazebo's "
                "backward-difference added mass diverges when |X_dot| >= m per axis; use "
                "the implicit added mass (uwval simulate --added-mass implicit; an experiment's "
                'added_mass = "implicit"; GazeboModel(added_mass=AddedMass.IMPLICIT)) or a '
                "Gazebo-stable variant"
            )
    return out


class Simulator:
    """Incremental stepping of one vehicle, for live runs and teleop.

    ``advance_to(t_ns)`` steps the physics up to sim time ``t_ns`` and returns the publish
    ticks crossed (the one at t = 0 included on the first call); ``set_wrench`` /
    ``set_current`` override the input profile from the current step on.
    """

    def __init__(
        self,
        vehicle: Vehicle,
        inputs: InputProfile | None = None,
        *,
        dt: float = 1e-3,
        publish_rate: float = 50.0,
        model: GazeboModel = PLUGIN_ADDED_MASS,
        camera_offset: Sequence[float] = DEFAULT_CAMERA_OFFSET,
        initial: InitialState = AT_REST,
    ) -> None:
        self.vehicle = vehicle
        self.inputs = inputs if inputs is not None else constant_inputs()
        self.dt = dt
        self.publish_rate = publish_rate
        self.dt_ns, self.publish_every = _check_timing(dt, publish_rate)
        self.model = model
        self.camera_offset = tuple(float(x) for x in camera_offset)
        q0 = np.asarray(initial.orientation, dtype=np.float64)
        q0 = q0 / np.linalg.norm(q0)
        self.state: tuple[Any, ...] = initial_state(
            1, initial.position, q0.tolist(), initial.velocity
        )
        self.step = 0
        self._published_step = -1
        self._force_override: F64 | None = None
        self._torque_override: F64 | None = None
        self._current_override: F64 | None = None
        self._chunk_start = 0
        self._chunk_end = 0
        self._chunk: tuple[list[float], ...] = ()
        self._has_current = False
        self._kernel_for_current(
            not (self.inputs.current.is_zero() and not np.any(vehicle.default_current))
        )
        self.warnings = _warnings_for([vehicle], model.implicit)
        self.state = _with_history(self.state, self._current_at(0.0), model.implicit)
        if model.zero_prev_state and not model.implicit:
            self.state = _zero_history(self.state)

    # ------------------------------------------------------------------ control
    @property
    def t_ns(self) -> int:
        """Current sim time, ns."""
        return self.step * self.dt_ns

    def set_wrench(self, force: ArrayLike, torque: ArrayLike) -> None:
        """Hold this force (N) and torque (N m), in the profile's wrench frame, from now on."""
        self._force_override = np.asarray(force, dtype=np.float64).reshape(3)
        self._torque_override = np.asarray(torque, dtype=np.float64).reshape(3)
        self._chunk_end = 0

    def set_current(self, current: ArrayLike) -> None:
        """Hold this world ENU current (m/s) from now on."""
        self._current_override = np.asarray(current, dtype=np.float64).reshape(3)
        if np.any(self._current_override) and not self._has_current:
            self._kernel_for_current(True)
        self._chunk_end = 0

    def _kernel_for_current(self, has_current: bool) -> None:
        self._has_current = has_current
        self._params = build_params(
            [self.vehicle],
            self.dt,
            self.model,
            has_current=has_current,
            wrench_frame=self.inputs.wrench_frame,
        )
        self._kernel = get_kernel(self._params.structure)

    def _current_at(self, t_s: float) -> F64:
        c = self.inputs.current(np.array([t_s]))[0] + self.vehicle.default_current
        return np.asarray(c, dtype=np.float64)

    def _load_chunk(self, start: int) -> None:
        n = CHUNK_STEPS
        t = (start + np.arange(n)) * (self.dt_ns * 1e-9)
        f, tq, c = self.inputs.evaluate(t)
        if self._force_override is not None:
            f = np.broadcast_to(self._force_override, (n, 3))
        if self._torque_override is not None:
            tq = np.broadcast_to(self._torque_override, (n, 3))
        if self._current_override is not None:
            c = np.broadcast_to(self._current_override, (n, 3))
        c = c + self.vehicle.default_current
        cols = np.concatenate([f, tq, c], axis=1).T
        self._chunk = tuple(cols.tolist())
        self._chunk_start = start
        self._chunk_end = start + n

    def _tick(self) -> tuple[int, F64, F64, F64, F64]:
        s = self.state
        pos = np.array(s[0:3])
        quat = np.array(s[3:7])
        cam_p, cam_q = camera_poses(pos, quat, self.camera_offset)
        return self.t_ns, pos, quat, cam_p[0], cam_q[0]

    def _check(self) -> None:
        vel = self.state[7:13]
        if not all(abs(x) < DIVERGENCE_LIMIT for x in vel):  # also catches NaN
            hint = ("; " + " ".join(self.warnings)) if self.warnings else ""
            twist = ", ".join(f"{n}={x:.3g}" for n, x in zip("uvwpqr", vel, strict=True))
            raise DivergenceError(
                f"simulation of {self.vehicle.name} diverged by t = {self.t_ns * 1e-9:.3f} s "
                f"(body twist {twist}; limit {DIVERGENCE_LIMIT:g}){hint}",
                self.t_ns * 1e-9,
            )

    def advance_steps(self, n_steps: int, record: list[tuple[Any, ...]] | None = None) -> None:
        """Step ``n_steps`` steps; append the raw state at each publish tick to ``record``."""
        target = self.step + int(n_steps)
        pe = self.publish_every
        if self._published_step < 0 and self.step % pe == 0:
            if record is not None:
                record.append(self.state)
            self._published_step = self.step
        while self.step < target:
            if not (self._chunk_start <= self.step < self._chunk_end):
                self._load_chunk(self.step)
            end = min((self.step // pe + 1) * pe, target, self._chunk_end)
            ch = self._chunk
            self.state = self._kernel(
                end - self.step,
                self.step - self._chunk_start,
                self.state,
                self._params.values,
                *ch,
            )
            self.step = end
            if end % pe == 0:
                self._check()
                self._published_step = end
                if record is not None:
                    record.append(self.state)

    def advance_to(self, t_ns: int) -> list[tuple[int, F64, F64, F64, F64]]:
        """Step up to sim time ``t_ns`` (floored to a step); return the publish ticks crossed as
        ``(t_ns, vehicle_pos, vehicle_quat, camera_pos, camera_quat)``."""
        target = int(t_ns) // self.dt_ns
        ticks: list[tuple[int, F64, F64, F64, F64]] = []
        pe = self.publish_every
        if self._published_step < 0 and self.step % pe == 0:
            ticks.append(self._tick())
            self._published_step = self.step
        while self.step < target:
            nxt = min((self.step // pe + 1) * pe, target)
            self.advance_steps(nxt - self.step)
            if self.step % pe == 0:
                ticks.append(self._tick())
        return ticks


def _with_history(state: tuple[Any, ...], current: F64, implicit: bool) -> tuple[Any, ...]:
    """Set the added-mass history to the initial relative twist (explicit) or the initial
    body-frame current (implicit), as current gz-sim does on its first iteration (no spike).

    ``current`` is (3,) for one vehicle or (N, 3) for a batch; ``state`` holds floats or (N,)."""
    qx, qy, qz, qw = (np.asarray(state[i], dtype=np.float64) for i in range(3, 7))
    c = np.asarray(current, dtype=np.float64)
    cx, cy, cz = c[..., 0], c[..., 1], c[..., 2]
    # R^T c with R from the quaternion (columns of R dotted with c)
    cb0 = (
        (1 - 2 * (qy * qy + qz * qz)) * cx
        + 2 * (qx * qy + qw * qz) * cy
        + 2 * (qx * qz - qw * qy) * cz
    )
    cb1 = (
        2 * (qx * qy - qw * qz) * cx
        + (1 - 2 * (qx * qx + qz * qz)) * cy
        + 2 * (qy * qz + qw * qx) * cz
    )
    cb2 = (
        2 * (qx * qz + qw * qy) * cx
        + 2 * (qy * qz - qw * qx) * cy
        + (1 - 2 * (qx * qx + qy * qy)) * cz
    )
    cb = (cb0, cb1, cb2)
    hist = list(state[13:19])
    for i in range(3):
        val = cb[i] if implicit else np.asarray(state[7 + i]) - cb[i]
        hist[i] = float(val) if np.ndim(val) == 0 else np.asarray(val, dtype=np.float64)
    return (*state[:13], *hist)


def _zero_history(state: tuple[Any, ...]) -> tuple[Any, ...]:
    """gz-sim 8.0-8.11: ``prevState`` starts at zero, so the first step's backward difference
    sees the whole initial relative twist (an added-mass kick when a current flows)."""
    hist = [np.zeros_like(h, dtype=np.float64) if np.ndim(h) else 0.0 for h in state[13:19]]
    return (*state[:13], *hist)


def _result_from_records(
    records: list[tuple[Any, ...]] | F64,
    period_ns: int,
    camera_offset: Sequence[float],
    info: dict[str, Any],
) -> SimResult:
    arr = np.asarray(records, dtype=np.float64).reshape(-1, N_STATE)
    n = arr.shape[0]
    t = np.arange(n, dtype=np.int64) * period_ns
    pos = np.ascontiguousarray(arr[:, 0:3])
    quat = np.ascontiguousarray(arr[:, 3:7])
    vel = np.ascontiguousarray(arr[:, 7:13])
    cam_p, cam_q = camera_poses(pos, quat, camera_offset)
    src = f"simulator:{info.get('vehicle', '')}"
    vstream = PoseStream.from_arrays(t, pos, quat, frame="enu", topic=VEHICLE_TOPIC, source=src)
    cstream = PoseStream.from_arrays(t, cam_p, cam_q, frame="enu", topic=CAMERA_TOPIC, source=src)
    return SimResult(vstream, cstream, vel, info)


def simulate(
    vehicle: Vehicle,
    inputs: InputProfile | None,
    duration_s: float,
    *,
    dt: float = 1e-3,
    publish_rate: float = 50.0,
    seed: int = 0,
    model: GazeboModel = PLUGIN_ADDED_MASS,
    camera_offset: Sequence[float] = DEFAULT_CAMERA_OFFSET,
    initial: InitialState = AT_REST,
) -> SimResult:
    """Run one vehicle for ``duration_s`` seconds of sim time; poses at ``publish_rate`` Hz.

    The physics is deterministic; ``seed`` is recorded in ``info`` (the run's identity in an
    experiment). Raises :class:`SimulationError` if the run diverges (e.g. Gazebo's explicit
    added mass with |X_dot| >= m), naming the time and axis.
    """
    if not (duration_s >= 0 and math.isfinite(duration_s)):
        raise SimulationError(f"duration must be >= 0 s, got {duration_s}")
    sim = Simulator(
        vehicle,
        inputs,
        dt=dt,
        publish_rate=publish_rate,
        model=model,
        camera_offset=camera_offset,
        initial=initial,
    )
    n_ticks = round(duration_s * 1e9) // (sim.dt_ns * sim.publish_every)
    records: list[tuple[Any, ...]] = []
    t0 = time.perf_counter()
    sim.advance_steps(n_ticks * sim.publish_every, records)
    wall = time.perf_counter() - t0
    info = _info(vehicle, sim.dt, publish_rate, seed, model)
    info["wrench_frame"] = sim.inputs.wrench_frame
    info.update(steps=sim.step, wall_time_s=wall, warnings=list(sim.warnings))
    return _result_from_records(records, sim.dt_ns * sim.publish_every, camera_offset, info)


@dataclass
class TickChunk:
    """Consecutive publish ticks of a streamed run (arrays of one chunk; ENU world, FLU body).

    ``t`` int64 ns of sim time; ``position``/``orientation`` the vehicle (m, x y z w),
    ``camera_position``/``camera_orientation`` the following camera, ``velocity`` (N, 6)
    body twist (m/s, rad/s, FLU). Values are those :func:`simulate` returns for these ticks.
    """

    t: NDArray[np.int64]
    position: F64
    orientation: F64
    camera_position: F64
    camera_orientation: F64
    velocity: F64

    def __len__(self) -> int:
        return int(self.t.shape[0])


class SimulationStream:
    """One vehicle's run, stepped and handed out chunk by chunk (bounded memory).

    Iterating yields :class:`TickChunk` s of at most ``chunk_ticks`` publish ticks, in time
    order, from the initial pose at t = 0 to the last whole publish period within
    ``duration_s``: the same ticks and the same numbers as :func:`simulate` (same stepping,
    same camera and quaternion arithmetic, row by row), but only one chunk is held at a
    time, so an hour at 100 Hz costs a few MB instead of hundreds. ``info`` is filled as
    :func:`simulate` fills it (``steps``, ``wall_time_s`` of the physics, ``warnings``) once
    the iteration has finished. Takes :func:`simulate`'s keyword arguments.
    """

    def __init__(
        self,
        vehicle: Vehicle,
        inputs: InputProfile | None,
        duration_s: float,
        *,
        chunk_ticks: int = 1000,
        background: bool | None = None,
        dt: float = 1e-3,
        publish_rate: float = 50.0,
        seed: int = 0,
        model: GazeboModel = PLUGIN_ADDED_MASS,
        camera_offset: Sequence[float] = DEFAULT_CAMERA_OFFSET,
        initial: InitialState = AT_REST,
    ) -> None:
        if not (duration_s >= 0 and math.isfinite(duration_s)):
            raise SimulationError(f"duration must be >= 0 s, got {duration_s}")
        if chunk_ticks < 1:
            raise SimulationError(f"chunk_ticks must be >= 1, got {chunk_ticks}")
        self.sim = Simulator(
            vehicle,
            inputs,
            dt=dt,
            publish_rate=publish_rate,
            model=model,
            camera_offset=camera_offset,
            initial=initial,
        )
        self.chunk_ticks = int(chunk_ticks)
        self.camera_offset = tuple(float(x) for x in camera_offset)
        self.period_ns = self.sim.dt_ns * self.sim.publish_every
        self.n_ticks = round(duration_s * 1e9) // self.period_ns
        self.info = _info(vehicle, self.sim.dt, publish_rate, seed, model)
        self.info["wrench_frame"] = self.sim.inputs.wrench_frame
        self.info["warnings"] = list(self.sim.warnings)
        self._started = False
        self._spec = (vehicle, inputs, duration_s)
        self._kwargs: dict[str, Any] = {
            "chunk_ticks": chunk_ticks,
            "dt": dt,
            "publish_rate": publish_rate,
            "seed": seed,
            "model": model,
            "camera_offset": tuple(camera_offset),
            "initial": initial,
        }
        steps = self.n_ticks * self.sim.publish_every
        self.background = _can_step_elsewhere() and (
            background if background is not None else steps >= BACKGROUND_MIN_STEPS
        )

    def __iter__(self) -> Iterator[TickChunk]:
        if self._started:
            raise SimulationError("a SimulationStream can be iterated once")
        self._started = True
        if self.background:
            return self._iter_elsewhere()
        return self._iter_here()

    def _iter_elsewhere(self) -> Iterator[TickChunk]:
        """Step the physics in a child process that runs ahead of the consumer (the bridge
        and the recorder use the other core); chunks come back through a pipe, whose
        fixed capacity holds the child back when it is far ahead (bounded memory)."""
        import multiprocessing as mp

        ctx = mp.get_context("spawn")  # no fork of a process that may run threads
        parent, child = ctx.Pipe(duplex=False)
        proc = ctx.Process(
            target=_stream_worker,
            args=(child, self._spec, self._kwargs),
            name="uwval-physics",
            daemon=True,
        )
        proc.start()
        child.close()
        try:
            while True:
                try:
                    kind, payload = parent.recv()
                except EOFError:
                    raise SimulationError(
                        f"the physics process of {self.sim.vehicle.name} died "
                        f"(exit code {proc.exitcode})"
                    ) from None
                if kind == "chunk":
                    yield payload
                elif kind == "done":
                    self.info.update(payload)
                    return
                else:
                    raise payload
        finally:
            parent.close()
            if proc.is_alive():
                proc.kill()
            proc.join()

    def _iter_here(self) -> Iterator[TickChunk]:
        sim, pe = self.sim, self.sim.publish_every
        done = 0  # ticks stepped after the initial one
        first_tick = 0
        wall = 0.0
        while True:
            records: Any = []
            k = min(
                self.chunk_ticks - (1 if done == 0 and first_tick == 0 else 0), self.n_ticks - done
            )
            t0 = time.perf_counter()
            sim.advance_steps(k * pe, records)
            wall += time.perf_counter() - t0
            done += k
            if len(records):
                yield self._chunk(records, first_tick)
                first_tick += len(records)
            if done >= self.n_ticks:
                break
        self.info.update(steps=sim.step, wall_time_s=wall, warnings=list(sim.warnings))

    def _chunk(self, records: list[tuple[Any, ...]], first_tick: int) -> TickChunk:
        """The arithmetic of :func:`_result_from_records`, on this chunk's rows."""
        arr = np.asarray(records, dtype=np.float64).reshape(-1, N_STATE)
        n = arr.shape[0]
        t = (first_tick + np.arange(n, dtype=np.int64)) * self.period_ns
        pos = np.ascontiguousarray(arr[:, 0:3])
        quat = _unit_rows(np.ascontiguousarray(arr[:, 3:7]))
        vel = np.ascontiguousarray(arr[:, 7:13])
        cam_p, cam_q = camera_poses(pos, quat, self.camera_offset)
        return TickChunk(t, pos, quat, cam_p, _unit_rows(cam_q), vel)


#: Runs of at least this many physics steps are stepped in a child process by default
#: (starting one costs ~0.3 s; an hour at 1 ms is 3.6M steps, ~9 s of physics).
BACKGROUND_MIN_STEPS = 1_000_000


def _can_step_elsewhere() -> bool:
    """A child process can be started here (not inside a daemonic pool worker)."""
    import multiprocessing as mp

    return not mp.current_process().daemon


def _stream_worker(conn: Any, spec: tuple[Any, ...], kwargs: dict[str, Any]) -> None:
    """Child process of :meth:`SimulationStream._iter_elsewhere`: the same stream, inline."""
    try:
        stream = SimulationStream(*spec, background=False, **kwargs)
        for chunk in stream:
            conn.send(("chunk", chunk))
        conn.send(("done", stream.info))
    except Exception as exc:  # re-raised by the consumer, at the same tick
        conn.send(("error", exc))
    finally:
        conn.close()


def _unit_rows(quat: F64) -> F64:
    """``PoseStream.from_arrays``' normalisation of (N, 4) quaternions: every row divided by
    its norm when one is more than 1e-9 from unit (the kernel keeps them unit, so in practice
    nothing changes; the rule is the same row arithmetic per chunk)."""
    norms = np.linalg.norm(quat, axis=1)
    if quat.shape[0] and bool((np.abs(norms - 1.0) > 1e-9).any()):
        return np.asarray(quat / norms[:, None])
    return quat


def _info(
    vehicle: Vehicle, dt: float, publish_rate: float, seed: int, model: GazeboModel
) -> dict[str, Any]:
    """A run's description (the log's and the manifest's ``sim`` record). The flat switches
    (``implicit_added_mass``, ``legacy_coriolis``, ``fossen_coriolis``, ``legacy_gz8``) stay
    for readers of earlier manifests; ``model`` holds the whole :class:`GazeboModel`."""
    return {
        "vehicle": vehicle.name,
        "vehicle_source": vehicle.source,
        "vehicle_notes": list(vehicle.notes),
        "dt": dt,
        "publish_rate": publish_rate,
        "seed": seed,
        "implicit_added_mass": model.implicit,
        "legacy_coriolis": model.legacy_coriolis,
        "fossen_coriolis": model.fossen,
        "legacy_gz8": model.legacy_gz8,
        "model": model.to_dict(),
    }


def simulate_batch(
    vehicles: Sequence[Vehicle] | Vehicle,
    inputs_list: Sequence[InputProfile] | InputProfile,
    duration_s: float,
    *,
    dt: float = 1e-3,
    publish_rate: float = 50.0,
    seed: int = 0,
    model: GazeboModel = PLUGIN_ADDED_MASS,
    camera_offset: Sequence[float] = DEFAULT_CAMERA_OFFSET,
    progress: Callable[[float], None] | None = None,
) -> list[SimResult]:
    """Run N vehicles in one vectorised state (each state variable an (N,) array).

    ``vehicles`` and ``inputs_list`` are sequences of equal length, or one of them a single
    item used for every run. Results equal those of :func:`simulate` per run (same equations
    and step order; floating-point results agree to rounding). All runs must share the wrench
    frame. A diverging run raises :class:`SimulationError` naming it. ``progress`` is called
    with the completed fraction (0..1] after each chunk of steps (e.g. to drive a rich bar).
    """
    vs = [vehicles] if isinstance(vehicles, Vehicle) else list(vehicles)
    ins = [inputs_list] if isinstance(inputs_list, InputProfile) else list(inputs_list)
    if len(vs) == 1 and len(ins) > 1:
        vs = vs * len(ins)
    if len(ins) == 1 and len(vs) > 1:
        ins = ins * len(vs)
    if len(vs) != len(ins) or not vs:
        raise SimulationError(
            f"simulate_batch needs as many vehicles as input profiles, got {len(vs)} and {len(ins)}"
        )
    frames = {p.wrench_frame for p in ins}
    if len(frames) > 1:
        raise SimulationError("simulate_batch: all input profiles must share one wrench_frame")
    n = len(vs)
    if n == 1:
        return [
            simulate(
                vs[0],
                ins[0],
                duration_s,
                dt=dt,
                publish_rate=publish_rate,
                seed=seed,
                model=model,
                camera_offset=camera_offset,
            )
        ]
    dt_ns, pe = _check_timing(dt, publish_rate)
    has_current = any(not p.current.is_zero() for p in ins) or any(
        bool(np.any(v.default_current)) for v in vs
    )
    params = build_params(vs, dt, model, has_current=has_current, wrench_frame=frames.pop())
    kernel = get_kernel(params.structure)
    default_cur = np.stack([v.default_current for v in vs])  # (N, 3)
    cur0 = np.stack([p.current(np.array([0.0]))[0] for p in ins]) + default_cur
    state = _with_history(initial_state(n), cur0, model.implicit)
    if model.zero_prev_state and not model.implicit:
        state = _zero_history(state)
    n_ticks = round(duration_s * 1e9) // (dt_ns * pe)
    total = n_ticks * pe
    rec = np.empty((n_ticks + 1, N_STATE, n))
    rec[0] = np.asarray(state)
    chunk = max(pe, (CHUNK_STEPS // pe) * pe)
    t0 = time.perf_counter()
    step = 0
    tick = 0
    with np.errstate(all="ignore"):
        while step < total:
            m = min(chunk, total - step)
            ts = (step + np.arange(m)) * (dt_ns * 1e-9)
            cols = np.empty((9, m, n))
            for i, prof in enumerate(ins):
                f, tq, c = prof.evaluate(ts)
                cols[0:3, :, i] = f.T
                cols[3:6, :, i] = tq.T
                cols[6:9, :, i] = (c + default_cur[i]).T
            k = 0
            while k < m:
                state = kernel(pe, k, state, params.values, *cols)
                k += pe
                tick += 1
                rec[tick] = np.asarray(state)
                vel = rec[tick, 7:13]
                bad = ~(np.abs(vel) < DIVERGENCE_LIMIT)
                if bad.any():
                    i_run = int(np.flatnonzero(bad.any(axis=0))[0])
                    raise DivergenceError(
                        f"batched run {i_run} ({vs[i_run].name}) diverged at "
                        f"t = {tick * pe * dt_ns * 1e-9:.3f} s; "
                        + " ".join(_warnings_for([vs[i_run]], model.implicit)),
                        tick * pe * dt_ns * 1e-9,
                    )
            step += m
            if progress is not None:
                progress(step / total)
    wall = time.perf_counter() - t0
    out = []
    for i, v in enumerate(vs):
        info = _info(v, dt, publish_rate, seed, model)
        info["wrench_frame"] = ins[i].wrench_frame
        info.update(
            steps=total,
            wall_time_s=wall,
            batch_size=n,
            warnings=_warnings_for([v], model.implicit),
        )
        out.append(_result_from_records(rec[:, :, i], dt_ns * pe, camera_offset, info))
    return out


__all__ = [
    "CAMERA_TOPIC",
    "VEHICLE_TOPIC",
    "Constant",
    "SimResult",
    "SimulationStream",
    "Simulator",
    "TickChunk",
    "camera_poses",
    "simulate",
    "simulate_batch",
]
