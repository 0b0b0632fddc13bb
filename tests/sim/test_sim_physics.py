"""Simulator physics against closed forms (DESIGN.md section 5) and gz-sim's own unit values."""

from __future__ import annotations

import math

import numpy as np
import pytest

from uwval.rotations import matrix_from_quat, quat_from_rpy, rpy_from_quat
from uwval.simulator import (
    Vehicle,
    constant_inputs,
    coriolis_matrix,
    damping_matrix,
    hydro_wrench_reference,
    load_vehicle,
    simulate,
    simulate_batch,
)
from uwval.simulator.dynamics import build_params, get_kernel, initial_state
from uwval.simulator.engine import InitialState
from uwval.simulator.errors import SimulationError
from uwval.simulator.model import AddedMass, CaSign, CoriolisEntries, GazeboModel

IMPLICIT = GazeboModel(added_mass=AddedMass.IMPLICIT)
IMPLICIT_FOSSEN = GazeboModel(added_mass=AddedMass.IMPLICIT, ca_sign=CaSign.FOSSEN)
LEGACY = GazeboModel(coriolis=CoriolisEntries.LEGACY)

TETHYS = load_vehicle("tethys")


def diag_ma(*vals: float) -> np.ndarray:
    return np.array(vals, dtype=float)


def one_axis_vehicle(**hydro: float) -> Vehicle:
    """Tethys' rigid body with only the given hydrodynamic parameters (neutral, CoB at CoG)."""
    return Vehicle("one-axis", TETHYS.mass, TETHYS.inertia, hydro=hydro)


# ---------------------------------------------------------------- closed forms
def test_surge_terminal_velocity_tethys_10N() -> None:
    r = simulate(TETHYS, constant_inputs(force=(10, 0, 0)), 100.0)
    u = r.velocity[-1, 0]
    assert u == pytest.approx(1.26712, rel=5e-3)
    # closed form (-d1 + sqrt(d1^2 + 4 d2 F)) / (2 d2) with d1 = 0
    assert u == pytest.approx(math.sqrt(10 / 6.2282), rel=5e-3)
    # nothing else moves: no sway, heave, rotation
    assert np.abs(r.velocity[:, 1:]).max() < 1e-12
    assert np.abs(r.vehicle.position[:, 1:]).max() < 1e-12


def test_quadratic_step_response_is_tanh() -> None:
    force, d2 = 10.0, 6.2282
    m_eff = TETHYS.mass + 4.876161  # M = m - X_udot
    r = simulate(TETHYS, constant_inputs(force=(force, 0, 0)), 30.0)
    t = r.vehicle.seconds
    u_ss = math.sqrt(force / d2)
    expected = u_ss * np.tanh(t * math.sqrt(force * d2) / m_eff)
    assert np.abs(r.velocity[:, 0] - expected).max() < 2e-3 * u_ss
    # and the position is its integral ln(cosh) form
    x_expected = m_eff / d2 * np.log(np.cosh(t * math.sqrt(force * d2) / m_eff))
    assert np.abs(r.vehicle.position[:, 0] - x_expected).max() < 5e-3 * x_expected[-1]


def test_linear_time_constant() -> None:
    d1, force = 20.0, 10.0
    v = one_axis_vehicle(xDotU=-4.876161, xU=-d1)
    m_eff = v.mass + 4.876161
    tau = m_eff / d1
    r = simulate(v, constant_inputs(force=(force, 0, 0)), 5 * tau)
    t = r.vehicle.seconds
    expected = force / d1 * (1 - np.exp(-t / tau))
    assert np.abs(r.velocity[:, 0] - expected).max() < 1e-3 * force / d1
    i_tau = int(np.argmin(np.abs(t - tau)))
    assert r.velocity[i_tau, 0] / (force / d1) == pytest.approx(
        1 - math.exp(-t[i_tau] / tau), abs=1e-3
    )


def test_coast_down_distance() -> None:
    d1, d2, u0 = 20.0, 6.2282, 1.0
    v = one_axis_vehicle(xDotU=-4.876161, xU=-d1, xUabsU=-d2)
    m_eff = v.mass + 4.876161
    r = simulate(v, None, 80.0, initial=InitialState(velocity=(u0, 0, 0, 0, 0, 0)))
    # M du/dt = -d1 u - d2 u^2  =>  x_inf = (M / d2) ln(1 + d2 u0 / d1)
    x_inf = m_eff / d2 * math.log(1 + d2 * u0 / d1)
    assert r.vehicle.position[-1, 0] == pytest.approx(x_inf, rel=2e-3)
    assert np.all(np.diff(r.velocity[:, 0]) <= 0)  # monotone slow-down, no overshoot


def test_yaw_rate_under_1Nm_torque() -> None:
    r = simulate(TETHYS, constant_inputs(torque=(0, 0, 1.0)), 25.0)
    assert r.velocity[-1, 5] == pytest.approx(0.0397559, rel=5e-3)
    # transient uses I_z - N_rdot
    i_eff = 41.98 + 33.46
    t = r.vehicle.seconds
    d2 = 632.698957
    expected = math.sqrt(1 / d2) * np.tanh(t * math.sqrt(d2) / i_eff)
    assert np.abs(r.velocity[:, 5] - expected).max() < 3e-3 * 0.0397559
    # the yaw angle follows the integral, wrapped to (-pi, pi]
    yaw = np.unwrap(rpy_from_quat(r.vehicle.orientation)[:, 2])
    assert yaw[-1] == pytest.approx(
        i_eff / d2 * math.log(math.cosh(t[-1] * math.sqrt(d2) / i_eff)), rel=5e-3
    )


def test_drift_towards_the_current() -> None:
    current = np.array([0.0, 0.3, 0.0])  # northward, world ENU
    r = simulate(TETHYS, constant_inputs(current=current), 30.0)
    world_vel = np.gradient(r.vehicle.position, r.vehicle.seconds, axis=0)
    assert np.all(np.diff(r.vehicle.position[:, 1]) >= 0)
    assert world_vel[-1, 1] == pytest.approx(0.3, rel=0.06)  # approaches the current from below
    assert world_vel[-1, 1] < 0.3
    assert np.abs(r.vehicle.position[:, [0, 2]]).max() < 1e-9
    # no current, no drift
    r0 = simulate(TETHYS, constant_inputs(), 5.0)
    assert np.abs(r0.vehicle.position).max() == 0.0


def test_current_is_a_world_vector() -> None:
    # a vehicle yawed by 90 deg (facing north) in an eastward current drifts east
    q = quat_from_rpy(np.array([[0.0, 0.0, math.pi / 2]]))[0]
    r = simulate(
        TETHYS,
        constant_inputs(current=(0.2, 0, 0)),
        20.0,
        initial=InitialState(orientation=tuple(q)),
    )
    assert r.vehicle.position[-1, 0] > 1.0
    assert abs(r.vehicle.position[-1, 1]) < 1e-6
    # in the body frame that is a drift to the right (negative sway)
    assert r.velocity[-1, 1] < -0.1


def test_neutral_buoyancy_at_rest_stays_at_rest() -> None:
    r = simulate(TETHYS, None, 20.0)
    assert np.abs(r.vehicle.position).max() < 1e-12
    assert np.abs(r.vehicle.orientation - [0, 0, 0, 1]).max() < 1e-12
    assert np.abs(r.velocity).max() < 1e-12


def test_negative_buoyancy_sinks_at_closed_form_speed() -> None:
    v = load_vehicle("bluerov2_heavy")
    assert v.buoyancy - v.weight == pytest.approx(1000 * 0.0134 * 9.8 - 13.5 * 9.8)
    r = simulate(v, None, 20.0, model=IMPLICIT)
    f = v.weight - v.buoyancy
    w_ss = (-33 + math.sqrt(33**2 + 4 * 190 * f)) / (2 * 190)
    assert r.velocity[-1, 2] == pytest.approx(-w_ss, rel=5e-3)
    assert r.vehicle.position[-1, 2] < 0


def test_buoyancy_moment_rights_the_vehicle() -> None:
    v = load_vehicle("bluerov2_heavy_stable")  # CoB 1 cm above CoG
    q0 = quat_from_rpy(np.array([[0.3, 0.0, 0.0]]))[0]
    r = simulate(v, None, 30.0, initial=InitialState(orientation=tuple(q0)))
    roll = rpy_from_quat(r.vehicle.orientation)[:, 0]
    assert roll[0] == pytest.approx(0.3)
    assert r.velocity[1, 3] < 0  # the restoring moment turns it back first
    assert abs(roll[-1]) < 0.05
    assert np.abs(roll).max() <= 0.3 + 1e-9


def test_heave_terminal_velocity_independent_of_added_mass_treatment() -> None:
    f = 10.0
    imp = simulate(
        load_vehicle("bluerov2_heavy"),
        constant_inputs(force=(0, 0, f)),
        10.0,
        model=IMPLICIT,
    )
    stable = simulate(load_vehicle("bluerov2_heavy_stable"), constant_inputs(force=(0, 0, f)), 10.0)
    net = f + 1000 * 0.0134 * 9.8 - 13.5 * 9.8
    w_ss = (-33 + math.sqrt(33**2 + 4 * 190 * net)) / (2 * 190)
    assert imp.velocity[-1, 2] == pytest.approx(w_ss, rel=1e-3)
    assert stable.velocity[-1, 2] == pytest.approx(w_ss, rel=1e-3)


# ---------------------------------------------------------------- conservation
def added_mass_only() -> Vehicle:
    return Vehicle(
        "am",
        TETHYS.mass,
        TETHYS.inertia,
        hydro={k: v for k, v in TETHYS.hydro.items() if "Dot" in k},
    )


NU0 = (0.5, 0.1, -0.1, 0.05, 0.1, -0.08)


def kinetic_energy(v: Vehicle, nu: np.ndarray) -> np.ndarray:
    m = v.rigid_body_mass_matrix() - v.added_mass_matrix()
    return 0.5 * np.einsum("ni,ij,nj->n", nu, m, nu)


def world_impulse(v: Vehicle, r) -> tuple[np.ndarray, np.ndarray]:  # type: ignore[no-untyped-def]
    m = v.rigid_body_mass_matrix() - v.added_mass_matrix()
    rot = matrix_from_quat(r.vehicle.orientation)
    body = r.velocity @ m.T
    lin = np.einsum("nij,nj->ni", rot, body[:, :3])
    # angular impulse about the CoG (the p x P part only adds position round-off)
    ang = np.einsum("nij,nj->ni", rot, body[:, 3:])
    return lin, ang


@pytest.mark.parametrize("implicit", [False, True])
@pytest.mark.parametrize("fossen", [False, True])
def test_energy_conserved_without_damping_and_current(implicit: bool, fossen: bool) -> None:
    v = added_mass_only()
    r = simulate(
        v,
        None,
        20.0,
        initial=InitialState(velocity=tuple(NU0)),
        model=GazeboModel(
            added_mass=AddedMass.IMPLICIT if implicit else AddedMass.EXPLICIT,
            ca_sign=CaSign.FOSSEN if fossen else CaSign.GAZEBO,
        ),
    )
    e = kinetic_energy(v, r.velocity)
    assert np.abs(e / e[0] - 1).max() < 5e-3
    assert np.abs(r.velocity).max() > 0.01  # it did move and rotate


def test_momentum_conserved_rigid_body() -> None:
    v = Vehicle("rigid", TETHYS.mass, np.diag([3.0, 20.0, 41.98]))
    r = simulate(v, None, 20.0, initial=InitialState(velocity=tuple(NU0)))
    lin, ang = world_impulse(v, r)
    assert np.abs(lin - lin[0]).max() < 1e-3 * np.linalg.norm(lin[0])
    assert np.abs(ang - ang[0]).max() < 1e-3 * np.linalg.norm(ang[0])
    e = kinetic_energy(v, r.velocity)
    assert np.abs(e / e[0] - 1).max() < 5e-3


def test_kirchhoff_impulse_conserved_with_fossen_sign_only() -> None:
    """gz applies +Cmat nu (= +C_A nu in Fossen's notation); Kirchhoff's impulse is conserved
    with Fossen's -C_A nu. This pins down which sign each switch uses."""
    v = added_mass_only()
    fossen = simulate(
        v, None, 20.0, initial=InitialState(velocity=tuple(NU0)), model=IMPLICIT_FOSSEN
    )
    lin, _ = world_impulse(v, fossen)
    assert np.abs(lin - lin[0]).max() < 2e-3 * np.linalg.norm(lin[0])
    gz = simulate(v, None, 20.0, initial=InitialState(velocity=tuple(NU0)), model=IMPLICIT)
    lin_gz, _ = world_impulse(v, gz)
    assert np.abs(lin_gz - lin_gz[0]).max() > 0.03 * np.linalg.norm(lin_gz[0])


# ---------------------------------------------------------------- gz-sim unit values
def test_gz_coriolis_known_values() -> None:
    c = coriolis_matrix(diag_ma(-1, -2, -3, -4, -5, -6), [1, 2, 3, 4, 5, 6])
    expected = np.array(
        [
            [0, 0, 0, 0, 9, -4],
            [0, 0, 0, -9, 0, 1],
            [0, 0, 0, 4, -1, 0],
            [0, 9, -4, 0, 36, -25],
            [-9, 0, 1, -36, 0, 16],
            [4, -1, 0, 25, -16, 0],
        ],
        dtype=float,
    )
    np.testing.assert_array_equal(c, expected)


@pytest.mark.parametrize(
    "state",
    [
        [1.0, 2.0, 3.0, 0.5, -1.0, 0.3],
        [-0.7, 0.0, 1.2, -0.3, 0.8, -0.1],
        [5.0, -3.0, 2.0, 1.0, -2.0, 4.0],
    ],
)
def test_gz_coriolis_skew_symmetric_and_passive(state: list[float]) -> None:
    c = coriolis_matrix(diag_ma(-10, -20, -30, -5, -15, -25), state)
    np.testing.assert_allclose(c + c.T, 0, atol=1e-12)
    assert abs(np.asarray(state) @ c @ np.asarray(state)) < 1e-12


def test_gz_coriolis_zero_cases() -> None:
    tethys_ma = diag_ma(-4.876, -126.325, -126.325, 0.0, -33.46, -33.46)
    assert not coriolis_matrix(tethys_ma, np.zeros(6)).any()
    assert not coriolis_matrix(np.zeros(6), [1, 2, 3, 4, 5, 6]).any()


def test_gz_coriolis_bug_regression_and_legacy_switch() -> None:
    ma = diag_ma(-3, -7, -13, -2, -5, -11)
    s = [0.5, 0.8, 1.2, 0.3, 0.6, 0.9]
    fixed = coriolis_matrix(ma, s)
    assert fixed[0, 5] == -7.0 * 0.8
    assert fixed[5, 0] == 7.0 * 0.8
    legacy = coriolis_matrix(ma, s, legacy=True)
    assert legacy[0, 5] == pytest.approx(5.6)  # wrong sign
    assert legacy[5, 0] == pytest.approx(-13.0 * 1.2)  # wrong index and sign
    diff = np.argwhere(fixed != legacy)
    assert sorted(map(tuple, diff)) == [(0, 5), (5, 0)]
    assert np.abs(legacy + legacy.T).max() > 1  # the legacy matrix is not skew-symmetric


def test_gz_munk_moment() -> None:
    ma = diag_ma(-5, -100, -100, 0, -10, -10)
    s = np.array([1.0, 0.5, 0, 0, 0, 0])
    c = coriolis_matrix(ma, s)
    assert (-c @ s)[5] == -47.5
    assert (-c @ s)[5] == (ma[1] - ma[0]) * s[0] * s[1]


def test_gz_coriolis_tethys_values() -> None:
    ma = diag_ma(-4.876161, -126.324739, -126.324739, 0.0, -33.46, -33.46)
    s = np.array([0.5, 0.3, -0.1, 0.0, 0.02, -0.01])
    c = coriolis_matrix(ma, s)
    np.testing.assert_allclose(c + c.T, 0, atol=1e-12)
    assert c[0, 4] == 126.324739 * (-0.1)
    assert c[5, 0] == 126.324739 * 0.3


def test_gz_damping_unit_values() -> None:
    lin = np.zeros((6, 6))
    qabs = np.zeros((6, 6, 6))
    quad = np.zeros((6, 6, 6))
    lin[0, 0], lin[1, 1], lin[2, 2] = -5.0, -10.0, -3.0
    s = np.array([2.0, 1.0, 3.0, 0, 0, 0])
    d = damping_matrix(lin, qabs, quad, s)
    np.testing.assert_array_equal(np.diag(d), [5, 10, 3, 0, 0, 0])
    np.testing.assert_array_equal((d @ s)[:3], [10, 10, 9])
    lin[:] = 0
    qabs[0, 0, 0] = -6.2282
    for u in (2.0, -2.0):
        d = damping_matrix(lin, qabs, quad, [u, 0, 0, 0, 0, 0])
        assert d[0, 0] == 6.2282 * 2.0
    qabs[:] = 0
    quad[0, 0, 0] = -94.2475
    assert damping_matrix(lin, qabs, quad, [-2.0, 0, 0, 0, 0, 0])[0, 0] == -94.2475 * 2.0
    quad[:] = 0
    quad[0, 0, 1] = -5.0  # xUV
    d = damping_matrix(lin, qabs, quad, [1.0, 3.0, 0, 0, 0, 0])
    assert d[0, 0] == 15.0
    lin[0, 0], qabs[0, 0, 0], quad[0, 0, 1] = -0.2, -6.2282, 0.0
    d = damping_matrix(lin, qabs, quad, [2.0, 0, 0, 0, 0, 0])
    assert d[0, 0] == 0.2 + 6.2282 * 2.0


def test_gz_damping_tethys_config() -> None:
    _, qabs, quad = TETHYS.damping_terms()
    s = np.array([1.0, 0.5, -0.3, 0.1, -0.05, 0.02])
    d = damping_matrix(np.zeros((6, 6)), qabs, quad, s)
    np.testing.assert_allclose(
        np.diag(d),
        [6.2282, 601.27 * 0.5, 601.27 * 0.3, 0.1916 * 0.1, 632.698957 * 0.05, 632.698957 * 0.02],
    )
    assert d[0, 1] == d[1, 0] == d[2, 3] == 0.0


# ---------------------------------------------------------------- kernel = gz's matrix form
def rich_vehicle() -> Vehicle:
    """Off-diagonal added mass, linear cross terms and both quadratic tensors, CoB offset."""
    hydro = dict(TETHYS.hydro)
    hydro.update(xDotV=-1.5, nDotV=-2.0, xU=-3.0, yR=-4.0, xUV=-5.0, nRabsV=-7.0, kP=-0.5)
    return Vehicle(
        "rich",
        50.0,
        np.array([[3.0, 0.1, 0.0], [0.1, 20.0, 0.2], [0.0, 0.2, 25.0]]),
        volume=0.05,
        center_of_buoyancy=np.array([0.01, -0.02, 0.05]),
        hydro=hydro,
    )


def one_step_expected(
    v: Vehicle,
    nu: np.ndarray,
    prev: np.ndarray,
    q: np.ndarray,
    cur: np.ndarray,
    wrench: np.ndarray,
    dt: float,
    legacy: bool,
    implicit: bool,
) -> np.ndarray:
    rot = matrix_from_quat(q[None])[0]
    s = nu.copy()
    s[:3] -= rot.T @ cur
    ma = v.added_mass_matrix()
    if implicit:
        cb_prev = prev[:3]
        hyd = hydro_wrench_reference(v, s, s, dt, legacy)  # damping + Coriolis only
        sdot = np.zeros(6)
        sdot[:3] = -(rot.T @ cur - cb_prev) / dt
        hyd = hyd + ma @ sdot
        m = v.rigid_body_mass_matrix() - ma
    else:
        hyd = hydro_wrench_reference(v, s, prev, dt, legacy)
        m = v.rigid_body_mass_matrix()
    ez = rot.T @ np.array([0.0, 0.0, 1.0])
    grav = np.zeros(6)
    grav[:3] = (v.buoyancy - v.weight) * ez
    grav[3:] = np.cross(v.center_of_buoyancy, v.buoyancy * ez)
    vl, w = nu[:3], nu[3:]
    crb = np.concatenate([-v.mass * np.cross(w, vl), -np.cross(w, v.inertia @ w)])
    return nu + dt * np.linalg.solve(m, hyd + grav + crb + wrench)


@pytest.mark.parametrize("legacy", [False, True])
@pytest.mark.parametrize("implicit", [False, True])
def test_kernel_matches_gz_matrix_form(legacy: bool, implicit: bool) -> None:
    rng = np.random.default_rng(5)
    v = rich_vehicle()
    dt = 1e-3
    params = build_params(
        [v],
        dt,
        GazeboModel(
            coriolis=CoriolisEntries.LEGACY if legacy else CoriolisEntries.FIXED,
            added_mass=AddedMass.IMPLICIT if implicit else AddedMass.EXPLICIT,
        ),
        has_current=True,
        wrench_frame="body",
    )
    kernel = get_kernel(params.structure)
    for _ in range(5):
        nu = rng.normal(0, 0.5, 6)
        prev = nu + rng.normal(0, 0.01, 6)
        q = rng.normal(size=4)
        q /= np.linalg.norm(q)
        cur = rng.normal(0, 0.3, 3)
        wrench = rng.normal(0, 5, 6)
        state = (0.0, 0.0, 0.0, *q, *nu, *prev)
        cols = [[x] for x in (*wrench, *cur)]
        out = kernel(1, 0, state, params.values, *cols)
        expected = one_step_expected(v, nu, prev, q, cur, wrench, dt, legacy, implicit)
        np.testing.assert_allclose(out[7:13], expected, rtol=1e-10, atol=1e-12)


def test_legacy_coriolis_changes_a_turning_run() -> None:
    inputs = constant_inputs(force=(10, 0, 0), torque=(0, 0, 1.0))
    fixed = simulate(TETHYS, inputs, 20.0)
    legacy = simulate(TETHYS, inputs, 20.0, model=LEGACY)
    gap = np.linalg.norm(fixed.vehicle.position - legacy.vehicle.position, axis=1).max()
    assert gap > 0.05
    straight = constant_inputs(force=(10, 0, 0))
    # surge only: v = r = 0, the two differing entries see zeros: identical runs
    np.testing.assert_array_equal(
        simulate(TETHYS, straight, 5.0).vehicle.position,
        simulate(TETHYS, straight, 5.0, model=LEGACY).vehicle.position,
    )


# ---------------------------------------------------------------- explicit vs implicit added mass
def test_explicit_added_mass_diverges_for_published_bluerov2() -> None:
    v = load_vehicle("bluerov2_heavy")
    assert v.explicit_added_mass_unstable_axes() == ["zDotW = -18.68 (|.| >= 13.5 kg)"]
    short = simulate(v, constant_inputs(force=(0, 0, 10)), 0.012, publish_rate=1000)
    assert any("zDotW" in w and "implicit added mass" in w for w in short.info["warnings"])
    acc = np.diff(short.velocity[:, 2])
    # the lagged feedback alternates the acceleration's sign with gain 18.68 / 13.5 > 1
    assert np.all(np.sign(acc[2:]) != np.sign(acc[1:-1]))
    assert abs(acc[-1]) > 3 * abs(acc[2])
    with pytest.raises(SimulationError, match=r"diverged.*zDotW"):
        simulate(v, constant_inputs(force=(0, 0, 10)), 2.0)


def test_implicit_added_mass_is_stable_and_quiet() -> None:
    v = load_vehicle("bluerov2_heavy")
    r = simulate(v, constant_inputs(force=(5, 0, 10), torque=(0, 0, 0.5)), 20.0, model=IMPLICIT)
    assert r.info["warnings"] == []
    assert np.all(np.isfinite(r.velocity))
    assert np.abs(r.velocity).max() < 2.0
    stable = simulate(load_vehicle("bluerov2_heavy_stable"), constant_inputs(force=(0, 0, 10)), 2.0)
    assert stable.info["warnings"] == []


def test_added_mass_slows_the_step_response() -> None:
    heavy = one_axis_vehicle(xDotU=-100.0, xUabsU=-6.2282)
    light = one_axis_vehicle(xUabsU=-6.2282)
    a = simulate(heavy, constant_inputs(force=(10, 0, 0)), 1.0).velocity[-1, 0]
    b = simulate(light, constant_inputs(force=(10, 0, 0)), 1.0).velocity[-1, 0]
    assert a == pytest.approx(10 / (TETHYS.mass + 100), rel=1e-2)
    assert b == pytest.approx(10 / TETHYS.mass, rel=1e-2)


# ---------------------------------------------------------------- batch
def test_batch_equals_single_runs_bit_for_bit() -> None:
    vehicles = [TETHYS, TETHYS.with_params(mass=140.0), load_vehicle("bluerov2_heavy_stable")]
    inputs = [
        constant_inputs(force=(10, 0, 0), torque=(0, 0, 1)),
        constant_inputs(force=(0, 5, 0), current=(0.1, 0.2, 0)),
        constant_inputs(force=(2, 0, 3), torque=(0.1, 0, 0), current=(0, 0, 0.05)),
    ]
    batch = simulate_batch(vehicles, inputs, 3.0)
    for v, inp, res in zip(vehicles, inputs, batch, strict=True):
        single = simulate(v, inp, 3.0)
        np.testing.assert_allclose(
            res.vehicle.position, single.vehicle.position, rtol=0, atol=1e-13
        )
        np.testing.assert_allclose(res.vehicle.orientation, single.vehicle.orientation, atol=1e-13)
        np.testing.assert_allclose(res.velocity, single.velocity, atol=1e-13)
        assert res.info["vehicle"] == v.name
        assert res.info["batch_size"] == 3


def test_batch_reports_the_diverging_run() -> None:
    with pytest.raises(SimulationError, match=r"batched run 1 \(bluerov2_heavy\)"):
        simulate_batch(
            [TETHYS, load_vehicle("bluerov2_heavy")], constant_inputs(force=(0, 0, 10)), 1.0
        )
    with pytest.raises(SimulationError, match="as many vehicles"):
        simulate_batch([TETHYS, TETHYS], [constant_inputs()] * 3, 1.0)


def test_initial_state_helper_shapes() -> None:
    assert len(initial_state(1)) == 19
    assert initial_state(4)[6].shape == (4,)


def test_fluid_added_mass_model_is_a_rigid_body_with_the_added_inertia() -> None:
    """FLUID_ADDED_MASS (the default experiment's model) steps a body whose spatial inertia is
    M = M_RB - Ma, as DART does with SDFormat's <fluid_added_mass>: one step of the kernel is
    Newton-Euler with Kirchhoff's velocity terms, F = -w x (M11 v), T = -w x (M22 w) - v x
    (M11 v) (Fossen 2011 eq. 6.43's -C_A plus C_RB), not the plugin's +C_A."""
    from uwval.simulator import FLUID_ADDED_MASS

    v = added_mass_only()
    dt = 1e-3
    m_total = v.rigid_body_mass_matrix() - v.added_mass_matrix()
    nu = np.array(NU0)
    lin, ang = nu[:3], nu[3:]
    p = m_total[:3, :3] @ lin
    h = m_total[3:, 3:] @ ang
    wrench = np.concatenate([-np.cross(ang, p), -np.cross(ang, h) - np.cross(lin, p)])
    expected = nu + dt * np.linalg.solve(m_total, wrench)
    r = simulate(v, None, 0.02, dt=dt, publish_rate=1000, initial=InitialState(velocity=NU0))
    fluid = simulate(
        v, None, 0.02, dt=dt, publish_rate=1000, initial=InitialState(velocity=NU0),
        model=FLUID_ADDED_MASS,
    )  # fmt: skip
    np.testing.assert_allclose(fluid.velocity[1], expected, rtol=1e-12, atol=1e-15)
    assert np.abs(r.velocity[1] - expected).max() > 1e-6  # the plugin's model is another one
