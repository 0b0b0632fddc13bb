"""Input profiles (vectorised), teleop key scripts and live stepping with Simulator."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from uwval.errors import ConfigError
from uwval.rotations import quat_from_rpy, rotate_vectors
from uwval.simulator import (
    CAMERA_TOPIC,
    VEHICLE_TOPIC,
    Constant,
    InitialState,
    InputProfile,
    KeyScript,
    PulseTrain,
    Ramp,
    Simulator,
    Step,
    camera_poses,
    constant_inputs,
    load_vehicle,
    simulate,
)
from uwval.simulator.errors import SimulationError
from uwval.simulator.inputs import signal_from_spec


def A(values: object) -> np.ndarray:
    """A float array (the profile and thruster types are annotated with float arrays)."""
    return np.asarray(values, dtype=np.float64)


T = np.array([0.0, 0.5, 0.999, 1.0, 1.5, 2.0, 3.0, 10.0])
TETHYS = load_vehicle()


def test_profiles_are_vectorised() -> None:
    np.testing.assert_array_equal(Constant(A([1, 2, 3]))(T), np.tile([1, 2, 3], (len(T), 1)))
    s = Step(A([0, 0, 5]), t0=1.0)(T)
    np.testing.assert_array_equal(s[:, 2], [0, 0, 0, 5, 5, 5, 5, 5])
    r = Ramp(A([2, 0, 0]), t0=1.0, t1=3.0)(T)
    np.testing.assert_allclose(r[:, 0], [0, 0, 0, 0, 0.5, 1.0, 2.0, 2.0])
    p = PulseTrain(A([0, 1, 0]), period=2.0, duty=0.25, t0=0.0, t_end=5.0)(T)
    np.testing.assert_array_equal(p[:, 1], [1, 0, 0, 0, 0, 1, 0, 0])
    both = (Step(A([1, 0, 0]), t0=1.0) + 2 * Constant(A([1, 0, 0])))(T)
    np.testing.assert_array_equal(both[:, 0], [2, 2, 2, 3, 3, 3, 3, 3])


@settings(max_examples=50, deadline=None)
@given(
    amp=st.floats(-50, 50),
    period=st.floats(0.1, 10),
    duty=st.floats(0, 1),
    t0=st.floats(0, 5),
)
def test_pulse_train_duty_cycle(amp: float, period: float, duty: float, t0: float) -> None:
    t = t0 + np.arange(0, 20 * period, period / 1000)
    out = PulseTrain(A([amp, 0, 0]), period=period, duty=duty, t0=t0)(t)[:, 0]
    on = out != 0
    if amp != 0:
        assert abs(on.mean() - duty) < 0.01
        assert set(np.unique(out)) <= {0.0, amp}
    # nothing before t0
    early = np.linspace(0, t0, 50)
    early = early[early < t0]
    assert not PulseTrain(A([amp, 0, 0]), period=period, duty=duty, t0=t0)(early).any()


@settings(max_examples=50, deadline=None)
@given(
    start=st.floats(-10, 10), end=st.floats(-10, 10), t0=st.floats(0, 5), width=st.floats(0.01, 5)
)
def test_ramp_is_bounded_and_monotone(start: float, end: float, t0: float, width: float) -> None:
    t = np.linspace(0, t0 + 2 * width, 500)
    r = Ramp(A([end, 0, 0]), t0=t0, t1=t0 + width, start=A([start, 0, 0]))(t)[:, 0]
    lo, hi = min(start, end), max(start, end)
    assert r.min() >= lo - 1e-9
    assert r.max() <= hi + 1e-9
    d = np.diff(r) * np.sign(end - start)
    assert (d >= -1e-12).all()
    assert r[0] == pytest.approx(start)
    assert r[-1] == pytest.approx(end)


def test_key_script_like_teleop_keyboard() -> None:
    ks = KeyScript.parse("i@0:2; i@1:3; j@1.5:2.5; t@0:1", force_step=10.0, torque_step=1.0)
    prof = InputProfile.from_keys(ks, current=(0, 0.1, 0))
    f, tq, c = prof.evaluate([0.5, 1.2, 1.6, 2.5, 3.5])
    np.testing.assert_array_equal(f[:, 0], [10, 20, 20, 10, 0])  # held keys add up
    np.testing.assert_array_equal(f[:, 2], [10, 0, 0, 0, 0])
    np.testing.assert_array_equal(tq[:, 2], [0, 0, 1, 0, 0])
    np.testing.assert_array_equal(c[:, 1], [0.1] * 5)
    with pytest.raises(ConfigError, match="unknown teleop key 'q'"):
        KeyScript.parse("q@0:1")
    with pytest.raises(ConfigError, match="KEY@START:END"):
        KeyScript.parse("i0:1")
    with pytest.raises(ConfigError, match="release time"):
        KeyScript.parse("i@2:1")


def test_key_script_drives_the_vehicle() -> None:
    r = simulate(TETHYS, InputProfile.from_keys("i@0:5"), 10.0)
    u = r.velocity[:, 0]
    t = r.vehicle.seconds
    assert u[t <= 5].argmax() == np.flatnonzero(t <= 5)[-1]  # accelerates while held
    assert np.all(np.diff(u[t > 5.05]) < 0)  # coasts after release


def test_signal_specs_from_toml_values() -> None:
    assert isinstance(signal_from_spec([1, 2, 3], "x"), Constant)
    s = signal_from_spec({"kind": "pulse", "value": [1, 0, 0], "period": 1.0, "duty": 0.5}, "x")
    np.testing.assert_array_equal(s(np.array([0.25, 0.75]))[:, 0], [1, 0])
    for bad, match in [
        ({"kind": "wave", "value": [1, 0, 0]}, "unknown profile kind 'wave'"),
        ({"kind": "step"}, "missing 'value'"),
        ({"kind": "step", "value": [1, 0]}, "3 finite numbers"),
        ({"kind": "ramp", "value": [1, 0, 0], "t0": 2.0, "t1": 1.0}, "t1 > t0"),
        ({"kind": "step", "value": [1, 0, 0], "period": 1}, "unknown key"),
        ("fast", "expected a 3-vector"),
    ]:
        with pytest.raises(ConfigError, match=match):
            signal_from_spec(bad, "force")  # type: ignore[arg-type]


def test_world_wrench_frame_rotates_into_the_body() -> None:
    q = quat_from_rpy(np.array([[0.0, 0.0, math.pi / 2]]))[0]  # facing north
    body = simulate(
        TETHYS, constant_inputs(force=(10, 0, 0)), 5.0, initial=InitialState(orientation=tuple(q))
    )
    world = simulate(
        TETHYS,
        constant_inputs(force=(10, 0, 0), wrench_frame="world"),
        5.0,
        initial=InitialState(orientation=tuple(q)),
    )
    assert body.vehicle.position[-1, 1] > 0.5  # body x = north
    assert world.vehicle.position[-1, 0] > 0.05  # world x = east = body -y: sway
    assert abs(world.vehicle.position[-1, 1]) < 1e-9
    with pytest.raises(ConfigError, match="wrench_frame"):
        constant_inputs(wrench_frame="ned")


def test_publish_ticks_and_streams() -> None:
    r = simulate(TETHYS, constant_inputs(force=(10, 0, 0)), 2.0)
    assert r.vehicle.topic == VEHICLE_TOPIC
    assert r.camera.topic == CAMERA_TOPIC
    assert r.vehicle.frame == r.camera.frame == "enu"
    assert len(r.vehicle) == 101  # t = 0 and every 20 ms
    np.testing.assert_array_equal(r.t, np.arange(101, dtype=np.int64) * 20_000_000)
    assert r.t.dtype == np.int64
    assert r.velocity.shape == (101, 6)
    assert r.info["vehicle"] == "tethys"
    assert r.info["dt"] == 1e-3
    assert r.info["steps"] == 2000
    r10 = simulate(TETHYS, None, 1.0, publish_rate=10.0, dt=0.002)
    np.testing.assert_array_equal(r10.t, np.arange(11) * 100_000_000)
    with pytest.raises(SimulationError, match="not a whole number of steps"):
        simulate(TETHYS, None, 1.0, publish_rate=30.0, dt=0.007)
    with pytest.raises(SimulationError, match="duration"):
        simulate(TETHYS, None, -1.0)


def test_camera_follows_and_looks_at_the_vehicle() -> None:
    q = quat_from_rpy(np.array([[0.1, -0.2, 1.0]]))
    pos = np.array([[5.0, -2.0, -3.0]])
    cp, cq = camera_poses(pos, q, (-3.0, 0.0, 1.0))
    yaw = 1.0
    np.testing.assert_allclose(cp[0], pos[0] + [-3 * math.cos(yaw), -3 * math.sin(yaw), 1.0])
    forward = rotate_vectors(cq, np.array([[1.0, 0.0, 0.0]]))[0]
    to_vehicle = (pos[0] - cp[0]) / np.linalg.norm(pos[0] - cp[0])
    np.testing.assert_allclose(forward, to_vehicle, atol=1e-12)
    left = rotate_vectors(cq, np.array([[0.0, 1.0, 0.0]]))[0]
    assert abs(left[2]) < 1e-12  # no roll: the camera's y axis stays horizontal


def test_simulator_live_stepping_matches_simulate() -> None:
    inputs = constant_inputs(force=(10, 0, 0), torque=(0, 0, 1))
    sim = Simulator(TETHYS, inputs)
    ticks = sim.advance_to(0)
    assert [t[0] for t in ticks] == [0]
    ticks += sim.advance_to(1_010_000_000)  # not on a tick boundary
    ticks += sim.advance_to(3_000_000_000)
    ref = simulate(TETHYS, inputs, 3.0)
    assert [t[0] for t in ticks] == ref.t.tolist()
    np.testing.assert_allclose(np.array([t[1] for t in ticks]), ref.vehicle.position, atol=1e-12)
    np.testing.assert_allclose(np.array([t[3] for t in ticks]), ref.camera.position, atol=1e-12)
    assert sim.t_ns == 3_000_000_000


def test_simulator_teleop_overrides() -> None:
    sim = Simulator(TETHYS, None)
    sim.advance_to(1_000_000_000)
    assert np.allclose(sim.state[0:3], 0)
    sim.set_wrench((20, 0, 0), (0, 0, 0))
    sim.advance_to(3_000_000_000)
    x_pushed = sim.state[0]
    assert x_pushed > 0.1
    sim.set_wrench((0, 0, 0), (0, 0, 0))
    sim.set_current((0, 0.5, 0))
    ticks = sim.advance_to(8_000_000_000)
    assert ticks[-1][1][1] > 0.5  # drifts north with the new current
    assert sim.state[7] < 0.3  # surge decays once the key is released


def test_thrusters_map_thrust_to_wrench() -> None:
    from uwval.simulator.thrusters import Thrusters

    # two surge thrusters 0.2 m either side of the centre line
    th = Thrusters(positions=A([[0, 0.2, 0], [0, -0.2, 0]]), directions=A([[1, 0, 0], [2, 0, 0]]))
    np.testing.assert_allclose(th.wrench([[10, 10]]), [[20, 0, 0, 0, 0, 0]], atol=1e-12)
    np.testing.assert_allclose(
        th.wrench([[10, -10]]), [[0, 0, 0, 0, 0, -4.0]], atol=1e-12
    )  # yaw right
    prof = th.inputs([Constant(A([5, 0, 0])), Step(A([5, 0, 0]), t0=1.0)])
    f, tq, _ = prof.evaluate([0.5, 1.5])
    np.testing.assert_allclose(f[:, 0], [5, 10])
    np.testing.assert_allclose(tq[:, 2], [-1.0, 0.0], atol=1e-12)
    r = simulate(TETHYS, th.inputs([Constant(A([5, 0, 0]))] * 2), 5.0)
    ref = simulate(TETHYS, constant_inputs(force=(10, 0, 0)), 5.0)
    np.testing.assert_allclose(r.vehicle.position, ref.vehicle.position, atol=1e-12)
    with pytest.raises(ConfigError, match="zero thrust direction"):
        Thrusters(positions=A([[0, 0, 0]]), directions=A([[0, 0, 0]]))
    with pytest.raises(ConfigError, match="expected 2 thrust values"):
        th.wrench([[1, 2, 3]])
