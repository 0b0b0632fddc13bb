"""The legacy mode of gz-sim 8.0-8.11 (issue 18, revised by issue 31 point 5): its Coriolis
entries and its zero initial ``prevState`` (Hydrodynamics.cc: ``prevState =
Eigen::VectorXd::Zero(6)`` in Configure, fixed in 8.12 by a first-iteration flag). The
unqualified ``abs(state(k))`` of the quadratic damping is *not* part of it: Hydrodynamics.cc
includes Eigen and protobuf headers that bring ``<stdlib.h>`` and the double overload, so real
builds very likely never truncated. The truncation stays as its own switch
(``GazeboModel.int_abs_damping``, ``--int-abs-damping``). Checked in closed form on gz-sim's
Tethys (m 147.8671 kg, X_udot -4.876161, X_u|u| -6.2282, no linear damping)."""

from __future__ import annotations

import json
import math
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
from cli_runner import run_uwval

from uwval.simulator import (
    CoriolisEntries,
    GazeboModel,
    constant_inputs,
    load_experiment,
    load_vehicle,
    simulate,
)

TETHYS = load_vehicle("tethys")
LEGACY_GZ8 = GazeboModel().as_legacy_gz8()
INT_ABS = GazeboModel(int_abs_damping=True)
M, XA, XUU = 147.8671, 4.876161, 6.2282  # kg, kg (|X_udot|), kg/m (|X_u|u||)


def test_zero_prevstate_kicks_the_first_step_with_a_current() -> None:
    c = 0.3  # m/s east; the vehicle starts at rest, so its relative surge is -c
    fixed = simulate(
        TETHYS,
        constant_inputs(current=(c, 0, 0)),
        2.0,
        model=GazeboModel(coriolis=CoriolisEntries.LEGACY),
    )
    legacy = simulate(TETHYS, constant_inputs(current=(c, 0, 0)), 2.0, model=LEGACY_GZ8)
    assert legacy.info["legacy_gz8"] and legacy.info["legacy_coriolis"]
    # the first backward difference sees -c / dt: an added-mass impulse X_a c, then the
    # explicit added mass of the next steps takes back X_a / (m + X_a) of it (geometric)
    kick = XA * c / (M + XA)
    # plus the quadratic drag of the current over the first 20 ms tick (|u_r| ~ c)
    drag = XUU * c * c * 0.02 / (M + XA)
    assert legacy.velocity[1, 0] == pytest.approx(kick + drag, rel=2e-3)
    assert abs(fixed.velocity[1, 0]) < 1e-3  # prevState from the real velocity: no kick
    gap = np.abs(legacy.vehicle.position[:, 0] - fixed.vehicle.position[:, 0]).max()
    assert gap > 0.01


def test_legacy_gz8_keeps_the_double_abs() -> None:
    """--legacy-gz8 no longer truncates: a surge from rest without current (where the legacy
    Coriolis entries and prevState see zeros) runs exactly as the fixed model does."""
    inputs = constant_inputs(force=(10.0, 0, 0))
    legacy = simulate(TETHYS, inputs, 20.0, model=LEGACY_GZ8)
    right = simulate(TETHYS, inputs, 20.0)
    assert legacy.info["legacy_gz8"] and not legacy.info["model"]["int_abs_damping"]
    np.testing.assert_array_equal(legacy.velocity, right.velocity)
    truncated = simulate(TETHYS, inputs, 20.0, model=INT_ABS)
    assert abs(truncated.velocity[-1, 0] - right.velocity[-1, 0]) > 0.1


def test_int_abs_removes_quadratic_damping_below_1_m_s() -> None:
    f = 10.0
    legacy = simulate(TETHYS, constant_inputs(force=(f, 0, 0)), 40.0, model=INT_ABS)
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
    sim = json.loads(out.stdout)["sim"]
    assert sim["legacy_gz8"] is True and sim["model"]["int_abs_damping"] is False
    out = run_uwval(
        "simulate", "--duration", "1", "--int-abs-damping", "--json", "-o", tmp_path / "a.mcap"
    )  # fmt: skip
    assert out.returncode == 0, out.stderr
    assert json.loads(out.stdout)["sim"]["model"]["int_abs_damping"] is True
    p = tmp_path / "e.toml"
    p.write_text("legacy_gz8 = true\nduration_s = 1.0\n[factors.force]\nlevels = [1.0]\n")
    assert load_experiment(p).runs()[0].simulate_kwargs()["model"] == LEGACY_GZ8
    p.write_text('legacy_gz8 = "yes"\n')
    bad = run_uwval("simulate", p, "-o", tmp_path / "x")
    assert bad.returncode == 2 and "'legacy_gz8' must be true or false" in bad.stderr


@pytest.mark.skipif(shutil.which("g++") is None, reason="no C++ compiler")
def test_what_an_unqualified_abs_of_a_double_does(tmp_path: Path) -> None:
    """The reading behind int_abs_damping: with only <cmath>/<cstdlib> (no <math.h>/<stdlib.h>,
    which add ``using std::abs`` globally) ``abs(0.7)`` is the int overload, 0. With
    <stdlib.h> included first, as Eigen and protobuf headers do in Hydrodynamics.cc, it is the
    double overload: why --legacy-gz8 no longer truncates."""
    src = tmp_path / "t.cpp"
    src.write_text(
        "#include <cmath>\n#include <cstdio>\n"
        'int main() { double v = 0.7; std::printf("%g %g", (double)abs(v), (double)abs(1.7)); }\n'
    )
    subprocess.run(["g++", "-std=c++17", str(src), "-o", str(tmp_path / "t")], check=True)
    out = subprocess.run([str(tmp_path / "t")], capture_output=True, text=True, check=True)
    assert out.stdout == "0 1"
    src.write_text("#include <stdlib.h>\n" + src.read_text())
    subprocess.run(["g++", "-std=c++17", str(src), "-o", str(tmp_path / "t")], check=True)
    out = subprocess.run([str(tmp_path / "t")], capture_output=True, text=True, check=True)
    assert out.stdout == "0.7 1.7"
