"""The complete legacy mode of gz-sim 8.0-8.11 (issue 18): its Coriolis entries, its zero
initial ``prevState`` (Hydrodynamics.cc: ``prevState = Eigen::VectorXd::Zero(6)`` in Configure,
fixed in 8.12 by a first-iteration flag) and its unqualified ``abs(state(k))`` in the
quadratic damping, which with only <cmath>/<cstdlib> declared is C's ``int abs(int)``: the
speed is truncated to an integer (fixed in 8.12 by ``std::abs``). Checked in closed form on
gz-sim's Tethys (m 147.8671 kg, X_udot -4.876161, X_u|u| -6.2282, no linear damping)."""

from __future__ import annotations

import json
import math
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
from cli_runner import run_uwval

from uwval.simulator import constant_inputs, load_experiment, load_vehicle, simulate

TETHYS = load_vehicle("tethys")
M, XA, XUU = 147.8671, 4.876161, 6.2282  # kg, kg (|X_udot|), kg/m (|X_u|u||)


def test_zero_prevstate_kicks_the_first_step_with_a_current() -> None:
    c = 0.3  # m/s east; the vehicle starts at rest, so its relative surge is -c
    fixed = simulate(TETHYS, constant_inputs(current=(c, 0, 0)), 2.0, legacy_coriolis=True)
    legacy = simulate(TETHYS, constant_inputs(current=(c, 0, 0)), 2.0, legacy_gz8=True)
    assert legacy.info["legacy_gz8"] and legacy.info["legacy_coriolis"]
    # the first backward difference sees -c / dt: an added-mass impulse X_a c, then the
    # explicit added mass of the next steps takes back X_a / (m + X_a) of it (geometric)
    kick = XA * c / (M + XA)
    assert legacy.velocity[1, 0] == pytest.approx(kick, rel=2e-3)
    assert abs(fixed.velocity[1, 0]) < 1e-3  # prevState from the real velocity: no kick
    gap = np.abs(legacy.vehicle.position[:, 0] - fixed.vehicle.position[:, 0]).max()
    assert gap > 0.01


def test_int_abs_removes_quadratic_damping_below_1_m_s() -> None:
    f = 10.0
    legacy = simulate(TETHYS, constant_inputs(force=(f, 0, 0)), 40.0, legacy_gz8=True)
    right = simulate(TETHYS, constant_inputs(force=(f, 0, 0)), 40.0)
    t, u = legacy.vehicle.seconds, legacy.velocity[:, 0]
    # below 1 m/s abs(u) is 0: no damping at all, u = F t / (m + X_a)
    slow = u < 0.95
    # (+2e-6 m/s: the explicit added mass lets the first 1 ms step accelerate with F / m)
    np.testing.assert_allclose(u[slow], f * t[slow] / (M + XA), rtol=1e-4, atol=5e-6)
    # between 1 and 2 m/s abs(u) is 1: damping X_u|u| * 1 * u, terminal speed F / X_u|u|
    fast = (u > 1.05) & (t > 20)
    dudt = np.gradient(u, t)[fast]
    np.testing.assert_allclose(dudt, (f - XUU * u[fast]) / (M + XA), rtol=0.02, atol=2e-5)
    # the right model (std::abs): u = u_ss tanh(t sqrt(F d2) / M), u_ss = 1.26712 m/s
    u_ss = math.sqrt(f / XUU)
    expect = u_ss * math.tanh(t[-1] * math.sqrt(f * XUU) / (M + XA))
    assert right.velocity[-1, 0] == pytest.approx(expect, rel=2e-3)
    assert u_ss + 0.1 < u[-1] < f / XUU  # past the right terminal speed, towards F / X_u|u|


def test_legacy_gz8_from_the_cli_and_the_experiment_file(tmp_path: Path) -> None:
    out = run_uwval(
        "simulate", "--current", "0.3,0,0", "--duration", "1", "--legacy-gz8", "--json",
        "-o", tmp_path / "l.mcap",
    )  # fmt: skip
    assert out.returncode == 0, out.stderr
    assert json.loads(out.stdout)["sim"]["legacy_gz8"] is True
    p = tmp_path / "e.toml"
    p.write_text("legacy_gz8 = true\nduration_s = 1.0\n[factors.force]\nlevels = [1.0]\n")
    assert load_experiment(p).runs()[0].simulate_kwargs()["legacy_gz8"] is True
    p.write_text('legacy_gz8 = "yes"\n')
    bad = run_uwval("simulate", p, "-o", tmp_path / "x")
    assert bad.returncode == 2 and "'legacy_gz8' must be true or false" in bad.stderr


@pytest.mark.skipif(shutil.which("g++") is None, reason="no C++ compiler")
def test_what_an_unqualified_abs_of_a_double_does(tmp_path: Path) -> None:
    """The reading behind legacy_abs: with <cmath>/<cstdlib> (no <math.h>/<stdlib.h>, which
    add ``using std::abs`` globally) ``abs(0.7)`` is the int overload, 0."""
    src = tmp_path / "t.cpp"
    src.write_text(
        "#include <cmath>\n#include <cstdio>\n"
        'int main() { double v = 0.7; std::printf("%g %g", (double)abs(v), (double)abs(1.7)); }\n'
    )
    subprocess.run(["g++", "-std=c++17", str(src), "-o", str(tmp_path / "t")], check=True)
    out = subprocess.run([str(tmp_path / "t")], capture_output=True, text=True, check=True)
    assert out.stdout == "0 1"
