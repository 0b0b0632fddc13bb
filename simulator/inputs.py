"""Input profiles: the wrench a thruster or keyboard teleop applies, and the water current.

* Force (N) and torque (N m) are expressed in the **body frame (FLU)** by default, as a thruster
  or a teleop node commanding a vehicle's link wrench applies them; ``wrench_frame="world"``
  takes them in world ENU instead (as gz's ApplyLinkWrench ``/world/.../wrench`` topic does).
  They act at the centre of gravity.
* The water current is a world ENU velocity (m/s), as gz-sim's ``/ocean_current`` topic.

Every signal is a function of time evaluated vectorised: ``signal(t)`` with ``t`` an (n,)
float array of seconds returns an (n, 3) array. Signals add (``a + b``) and scale (``2 * a``).
Kinds: :class:`Constant`, :class:`Step`, :class:`Ramp`, :class:`PulseTrain`, :class:`KeyScript`
(keys held as teleop_wrench_keyboard does: a held key adds a fixed increment on one axis).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Protocol, runtime_checkable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from uwval.errors import ConfigError

F64 = NDArray[np.float64]


def _vec3(v: ArrayLike, what: str) -> F64:
    a = np.asarray(v, dtype=np.float64).reshape(-1)
    if a.shape != (3,) or not np.all(np.isfinite(a)):
        raise ConfigError(f"{what} must be 3 finite numbers, got {v!r}")
    return a


@runtime_checkable
class Signal(Protocol):
    """A 3-vector signal of time: ``(n,) seconds -> (n, 3)``."""

    def __call__(self, t: F64) -> F64: ...

    def is_zero(self) -> bool: ...


class _SignalOps:
    def __add__(self, other: Signal) -> Sum:
        return Sum((self, other))  # type: ignore[arg-type]

    def __rmul__(self, k: float) -> Scaled:
        return Scaled(self, float(k))  # type: ignore[arg-type]

    def __mul__(self, k: float) -> Scaled:
        return Scaled(self, float(k))  # type: ignore[arg-type]


@dataclass(frozen=True)
class Constant(_SignalOps):
    """A constant 3-vector."""

    value: F64

    def __post_init__(self) -> None:
        object.__setattr__(self, "value", _vec3(self.value, "constant value"))

    def __call__(self, t: F64) -> F64:
        return np.broadcast_to(self.value, (np.shape(t)[0], 3)).copy()

    def is_zero(self) -> bool:
        return not bool(np.any(self.value))


@dataclass(frozen=True)
class Step(_SignalOps):
    """``before`` until ``t0`` (s), then ``after`` (both 3-vectors)."""

    after: F64
    t0: float = 0.0
    before: F64 = field(default_factory=lambda: np.zeros(3))

    def __post_init__(self) -> None:
        object.__setattr__(self, "after", _vec3(self.after, "step value"))
        object.__setattr__(self, "before", _vec3(self.before, "step initial value"))

    def __call__(self, t: F64) -> F64:
        on = (np.asarray(t) >= self.t0)[:, None]
        return np.where(on, self.after, self.before)

    def is_zero(self) -> bool:
        return not bool(np.any(self.after) or np.any(self.before))


@dataclass(frozen=True)
class Ramp(_SignalOps):
    """``start`` until ``t0``, linear to ``end`` at ``t1``, then ``end``."""

    end: F64
    t0: float = 0.0
    t1: float = 1.0
    start: F64 = field(default_factory=lambda: np.zeros(3))

    def __post_init__(self) -> None:
        object.__setattr__(self, "end", _vec3(self.end, "ramp end value"))
        object.__setattr__(self, "start", _vec3(self.start, "ramp start value"))
        if not self.t1 > self.t0:
            raise ConfigError(f"ramp needs t1 > t0, got t0={self.t0} t1={self.t1}")

    def __call__(self, t: F64) -> F64:
        s = np.clip((np.asarray(t) - self.t0) / (self.t1 - self.t0), 0.0, 1.0)[:, None]
        return self.start + s * (self.end - self.start)

    def is_zero(self) -> bool:
        return not bool(np.any(self.end) or np.any(self.start))


@dataclass(frozen=True)
class PulseTrain(_SignalOps):
    """``amplitude`` during the first ``duty`` fraction of each ``period`` (s) from ``t0``
    until ``t_end`` (``inf`` = forever), zero otherwise."""

    amplitude: F64
    period: float = 2.0
    duty: float = 0.5
    t0: float = 0.0
    t_end: float = math.inf

    def __post_init__(self) -> None:
        object.__setattr__(self, "amplitude", _vec3(self.amplitude, "pulse amplitude"))
        if not self.period > 0:
            raise ConfigError(f"pulse period must be > 0 s, got {self.period}")
        if not 0.0 <= self.duty <= 1.0:
            raise ConfigError(f"pulse duty must be in [0, 1], got {self.duty}")

    def __call__(self, t: F64) -> F64:
        t = np.asarray(t, dtype=np.float64)
        phase = np.mod(t - self.t0, self.period)
        # a small tolerance keeps the edges on exact multiples of the period deterministic
        on = (t >= self.t0) & (t < self.t_end) & (phase < self.duty * self.period - 1e-12)
        return np.where(on[:, None], self.amplitude, 0.0)

    def is_zero(self) -> bool:
        return not bool(np.any(self.amplitude)) or self.duty == 0.0


@dataclass(frozen=True)
class Sum(_SignalOps):
    """Sum of signals."""

    parts: tuple[Signal, ...]

    def __call__(self, t: F64) -> F64:
        out = np.zeros((np.shape(t)[0], 3))
        for p in self.parts:
            out += p(t)
        return out

    def is_zero(self) -> bool:
        return all(p.is_zero() for p in self.parts)


@dataclass(frozen=True)
class Scaled(_SignalOps):
    """A signal times a constant."""

    signal: Signal
    k: float

    def __call__(self, t: F64) -> F64:
        return self.k * self.signal(t)

    def is_zero(self) -> bool:
        return self.k == 0.0 or self.signal.is_zero()


# ---------------------------------------------------------------------- keyboard teleop
#: Key map in the style of teleop_twist_keyboard / teleop_wrench_keyboard: key -> (channel,
#: axis, sign). Channel 0 = force (N), 1 = torque (N m), body FLU axes.
TELEOP_KEYS: dict[str, tuple[int, int, float]] = {
    "i": (0, 0, +1.0),  # surge forward
    ",": (0, 0, -1.0),  # surge back
    "J": (0, 1, +1.0),  # sway left (shift = holonomic, as teleop_twist_keyboard)
    "L": (0, 1, -1.0),  # sway right
    "t": (0, 2, +1.0),  # heave up
    "b": (0, 2, -1.0),  # heave down
    "j": (1, 2, +1.0),  # yaw left (counter-clockwise seen from above)
    "l": (1, 2, -1.0),  # yaw right
    "u": (1, 0, +1.0),  # roll
    "o": (1, 0, -1.0),
    "y": (1, 1, +1.0),  # pitch (nose down in FLU)
    "n": (1, 1, -1.0),
}


class HeldKeys:
    """Wrench from keys held down on a live keyboard: each key stays active ``hold_s``
    seconds after its last (auto-)repeat, as a terminal reports a held key.

    ``force_step`` N and ``torque_step`` N m per held key on its :data:`TELEOP_KEYS` axis
    (body FLU); held keys add up.
    """

    def __init__(self, force_step: float, torque_step: float, hold_s: float) -> None:
        self.keys = TELEOP_KEYS
        self.force_step = force_step
        self.torque_step = torque_step
        self.hold_s = hold_s
        self.last_seen: dict[str, float] = {}

    def press(self, key: str, now: float) -> bool:
        """Record a key press at ``now`` (s); False when the key is not a teleop key."""
        if key not in self.keys:
            return False
        self.last_seen[key] = now
        return True

    def clear(self) -> None:
        """Release every key (the stop key)."""
        self.last_seen.clear()

    def wrench(self, now: float) -> tuple[F64, F64]:
        """(force N, torque N m) in the body frame from the keys held at ``now`` (s)."""
        force, torque = np.zeros(3), np.zeros(3)
        for key, seen in self.last_seen.items():
            if now - seen <= self.hold_s:
                ch, axis, sign = self.keys[key]
                if ch == 0:
                    force[axis] += sign * self.force_step
                else:
                    torque[axis] += sign * self.torque_step
        return force, torque


class LiveVehicle(Protocol):
    """What :class:`KeyboardTeleop` drives (``uwval.simulator.Simulator``'s overrides)."""

    def set_wrench(self, force: ArrayLike, torque: ArrayLike) -> None: ...

    def set_current(self, current: ArrayLike) -> None: ...


#: Step of the current towards north per ``+``/``-`` key, m/s.
CURRENT_KEY_STEP = 0.1


class KeyboardTeleop:
    """teleop_wrench_keyboard's behaviour on a live simulator: typed keys -> wrench, current.

    Teleop keys (:data:`TELEOP_KEYS`) are held (:class:`HeldKeys`); ``+``/``-`` change the
    current towards north (ENU y) by :data:`CURRENT_KEY_STEP`; ``k`` or space releases every
    key; ``q`` quits. ``current`` is the initial world ENU current, m/s.
    """

    def __init__(
        self, force_step: float, torque_step: float, hold_s: float, current: ArrayLike = (0, 0, 0)
    ) -> None:
        self.held = HeldKeys(force_step, torque_step, hold_s)
        self.current = _vec3(current, "current").copy()

    def handle(self, keys: str, now: float, vehicle: LiveVehicle) -> bool:
        """Apply the keys typed since the last call at sim time ``now`` (s), then hold the
        resulting wrench on ``vehicle``. Returns False when ``q`` asked to quit."""
        for ch in keys:
            if ch == "q":
                return False
            if ch in " k":
                self.held.clear()
            elif ch in "+-":
                self.current[1] += CURRENT_KEY_STEP if ch == "+" else -CURRENT_KEY_STEP
                vehicle.set_current(self.current)
            else:
                self.held.press(ch, now)
        vehicle.set_wrench(*self.held.wrench(now))
        return True


@dataclass(frozen=True)
class KeyPress:
    """One key held from ``t_start`` to ``t_end`` (s)."""

    key: str
    t_start: float
    t_end: float


@dataclass(frozen=True)
class KeyScript:
    """A scripted keyboard teleop session: while a key is held, its axis gets a constant
    increment (``force_step`` N or ``torque_step`` N m, body frame); held keys add up.

    Keys: :data:`TELEOP_KEYS` (``i``/``,`` surge, ``J``/``L`` sway, ``t``/``b`` heave,
    ``j``/``l`` yaw, ``u``/``o`` roll, ``y``/``n`` pitch).
    """

    presses: tuple[KeyPress, ...]
    force_step: float = 10.0
    torque_step: float = 1.0

    def __post_init__(self) -> None:
        for kp in self.presses:
            if kp.key not in TELEOP_KEYS:
                raise ConfigError(f"unknown teleop key {kp.key!r} (keys: {' '.join(TELEOP_KEYS)})")
            if not kp.t_end >= kp.t_start:
                raise ConfigError(
                    f"key {kp.key!r}: release time {kp.t_end} before press {kp.t_start}"
                )

    @classmethod
    def parse(cls, script: str, force_step: float = 10.0, torque_step: float = 1.0) -> KeyScript:
        """Parse ``"i@0:5, j@2:3.5"``: key ``i`` held from 0 s to 5 s, ``j`` from 2 s to 3.5 s."""
        presses = []
        for item in filter(None, (s.strip() for s in script.split(";" if ";" in script else ","))):
            try:
                key, span = item.rsplit("@", 1)
                a, b = span.split(":")
                presses.append(KeyPress(key, float(a), float(b)))
            except ValueError:
                raise ConfigError(
                    f"bad key press {item!r}: expected KEY@START:END (seconds)"
                ) from None
        return cls(tuple(presses), force_step, torque_step)

    def channel(self, which: int) -> KeyChannel:
        """The force (0) or torque (1) signal of this script."""
        return KeyChannel(self, which)


@dataclass(frozen=True)
class KeyChannel(_SignalOps):
    """Force or torque part of a :class:`KeyScript`."""

    script: KeyScript
    which: int

    def __call__(self, t: F64) -> F64:
        t = np.asarray(t, dtype=np.float64)
        out = np.zeros((t.shape[0], 3))
        step = self.script.force_step if self.which == 0 else self.script.torque_step
        for kp in self.script.presses:
            ch, axis, sign = TELEOP_KEYS[kp.key]
            if ch == self.which:
                out[:, axis] += np.where((t >= kp.t_start) & (t < kp.t_end), sign * step, 0.0)
        return out

    def is_zero(self) -> bool:
        return not any(TELEOP_KEYS[kp.key][0] == self.which for kp in self.script.presses)


# ---------------------------------------------------------------------- the profile
ZERO = Constant(np.zeros(3))


@dataclass(frozen=True)
class InputProfile:
    """What drives one run: wrench (force N, torque N m) and world current (m/s) over time.

    Attributes:
        force, torque: signals in ``wrench_frame`` (``"body"`` FLU, default, or ``"world"`` ENU).
        current: water current signal, world ENU, m/s.
        wrench_frame: ``"body"`` or ``"world"``.
    """

    force: Signal = ZERO
    torque: Signal = ZERO
    current: Signal = ZERO
    wrench_frame: str = "body"

    def __post_init__(self) -> None:
        if self.wrench_frame not in ("body", "world"):
            raise ConfigError(f"wrench_frame must be 'body' or 'world', got {self.wrench_frame!r}")

    def evaluate(self, t: ArrayLike) -> tuple[F64, F64, F64]:
        """Force, torque and current at times ``t`` (s): three (n, 3) arrays."""
        ts = np.atleast_1d(np.asarray(t, dtype=np.float64))
        return self.force(ts), self.torque(ts), self.current(ts)

    def with_(
        self,
        *,
        force: Signal | None = None,
        torque: Signal | None = None,
        current: Signal | None = None,
    ) -> InputProfile:
        """A copy with some signals replaced."""
        return InputProfile(
            force if force is not None else self.force,
            torque if torque is not None else self.torque,
            current if current is not None else self.current,
            self.wrench_frame,
        )

    @classmethod
    def from_keys(
        cls,
        script: KeyScript | str,
        current: Signal | ArrayLike = (0.0, 0.0, 0.0),
        force_step: float = 10.0,
        torque_step: float = 1.0,
    ) -> InputProfile:
        """A teleop session: force and torque from a key script, plus a current."""
        ks = (
            script
            if isinstance(script, KeyScript)
            else KeyScript.parse(script, force_step, torque_step)
        )
        cur = current if isinstance(current, Signal) else Constant(_vec3(current, "current"))
        return cls(ks.channel(0), ks.channel(1), cur)


def constant_inputs(
    force: Sequence[float] | ArrayLike = (0.0, 0.0, 0.0),
    torque: Sequence[float] | ArrayLike = (0.0, 0.0, 0.0),
    current: Sequence[float] | ArrayLike = (0.0, 0.0, 0.0),
    wrench_frame: str = "body",
) -> InputProfile:
    """Constant force (N), torque (N m) — body FLU unless ``wrench_frame="world"`` — and
    world ENU current (m/s)."""
    return InputProfile(
        Constant(_vec3(force, "force")),
        Constant(_vec3(torque, "torque")),
        Constant(_vec3(current, "current")),
        wrench_frame,
    )


def signal_from_spec(spec: dict[str, object] | float | Sequence[float], where: str) -> Signal:
    """A signal from a TOML value: a 3-vector (constant) or a table with ``kind`` one of
    ``constant`` (``value``), ``step`` (``value``, ``t0``, ``before``), ``ramp`` (``value``,
    ``t0``, ``t1``, ``start``), ``pulse`` (``value``, ``period``, ``duty``, ``t0``, ``t_end``)."""
    if isinstance(spec, (list, tuple)):
        return Constant(_vec3(spec, where))
    if not isinstance(spec, dict):
        raise ConfigError(f"{where}: expected a 3-vector or a table with 'kind', got {spec!r}")
    kind = spec.get("kind", "constant")
    allowed = {
        "constant": {"value"},
        "step": {"value", "t0", "before"},
        "ramp": {"value", "t0", "t1", "start"},
        "pulse": {"value", "period", "duty", "t0", "t_end"},
    }
    if kind not in allowed:
        raise ConfigError(f"{where}: unknown profile kind {kind!r} ({', '.join(allowed)})")
    extra = set(spec) - allowed[str(kind)] - {"kind"}
    if extra:
        raise ConfigError(f"{where}: unknown key(s) {sorted(extra)} for kind {kind!r}")
    if "value" not in spec:
        raise ConfigError(f"{where}: missing 'value' (3 numbers)")
    val = _vec3(spec["value"], f"{where}.value")  # type: ignore[arg-type]

    def num(key: str, default: float) -> float:
        x = spec.get(key, default)
        if isinstance(x, bool) or not isinstance(x, (int, float)):
            raise ConfigError(f"{where}.{key} must be a number, got {x!r}")
        return float(x)

    if kind == "constant":
        return Constant(val)
    if kind == "step":
        before = _vec3(spec.get("before", [0, 0, 0]), f"{where}.before")  # type: ignore[arg-type]
        return Step(val, num("t0", 0.0), before)
    if kind == "ramp":
        start = _vec3(spec.get("start", [0, 0, 0]), f"{where}.start")  # type: ignore[arg-type]
        return Ramp(val, num("t0", 0.0), num("t1", 1.0), start)
    return PulseTrain(
        val, num("period", 2.0), num("duty", 0.5), num("t0", 0.0), num("t_end", math.inf)
    )
