"""Wrench frame (body FLU / world ENU, as gz-sim's ApplyLinkWrench) in closed form, through the
experiment TOML and through ``uwval simulate --wrench-frame`` (issue 18)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
from cli_runner import run_uwval

from uwval.rotations import rpy_from_quat
from uwval.simulator import Vehicle, constant_inputs, load_experiment, simulate

MASS, IZZ = 10.0, 2.0  # kg, kg m^2
F, TAU = 4.0, 1.0  # N, N m
T = 3.0  # s


def free_body() -> Vehicle:
    """A neutrally buoyant rigid body with no hydrodynamics: motion in closed form."""
    return Vehicle(name="box", mass=MASS, inertia=np.diag([1.0, 1.0, IZZ]))


def body_frame_position(t: float, n: int = 200_001) -> tuple[float, float]:
    """Body force F along body x while yaw psi(s) = TAU s^2 / (2 IZZ):
    x''(s) = F/m cos psi, y''(s) = F/m sin psi; p(t) = int_0^t (t - s) a(s) ds (m, ENU)."""
    s = np.linspace(0.0, t, n)
    psi = TAU * s**2 / (2 * IZZ)
    w = (t - s) * F / MASS
    return float(np.trapezoid(w * np.cos(psi), s)), float(np.trapezoid(w * np.sin(psi), s))


def test_world_and_body_wrench_differ_as_in_closed_form() -> None:
    inputs = {
        fr: constant_inputs(force=(F, 0, 0), torque=(0, 0, TAU), wrench_frame=fr)
        for fr in ("body", "world")
    }
    runs = {fr: simulate(free_body(), ins, T) for fr, ins in inputs.items()}
    for fr, r in runs.items():
        assert r.info["wrench_frame"] == fr
        # the torque is about z in both frames (the body only yaws): psi = TAU t^2 / (2 IZZ)
        yaw = np.unwrap(rpy_from_quat(r.vehicle.orientation)[:, 2])
        t = r.vehicle.seconds
        np.testing.assert_allclose(yaw, TAU * t**2 / (2 * IZZ), atol=2e-3)
    # world: the force stays on east; x = F t^2 / (2 m), no north motion at all
    pw = runs["world"].vehicle.position[-1]
    assert math.isclose(pw[0], F * T**2 / (2 * MASS), rel_tol=2e-3)
    # (the body-axes step rotates the force with R at the step start: 3e-7 m over 3 s)
    assert abs(pw[1]) < 1e-5 and abs(pw[2]) < 1e-9
    # body: the force turns with the vehicle (psi(3 s) = 2.25 rad): a curved path
    pb = runs["body"].vehicle.position[-1]
    ex, ey = body_frame_position(T)
    assert abs(pb[0] - ex) < 2e-3 and abs(pb[1] - ey) < 2e-3
    # the two differ by much more than the discretisation error
    assert math.hypot(pw[0] - pb[0], pw[1] - pb[1]) > 0.2


def test_experiment_toml_wrench_frame_reaches_every_run(tmp_path: Path) -> None:
    base = 'vehicle = "tethys"\nduration_s = 1.0\n[factors.force]\nlevels = [1.0, 2.0]\n'
    for frame in ("body", "world"):
        p = tmp_path / f"{frame}.toml"
        p.write_text(f'wrench_frame = "{frame}"\n' + base)
        assert {r.inputs.wrench_frame for r in load_experiment(p).runs()} == {frame}
    p = tmp_path / "default.toml"
    p.write_text(base)
    assert {r.inputs.wrench_frame for r in load_experiment(p).runs()} == {"body"}


def test_simulate_cli_wrench_frame(tmp_path: Path) -> None:
    out = run_uwval(
        "simulate", "--force", "10,0,0", "--torque", "0,0,1", "--duration", "1",
        "--wrench-frame", "world", "--json", "-o", tmp_path / "w.mcap",
    )  # fmt: skip
    assert out.returncode == 0, out.stderr
    assert json.loads(out.stdout)["sim"]["wrench_frame"] == "world"
    bad = run_uwval("simulate", "--wrench-frame", "ned", "-o", tmp_path / "b.mcap")
    assert bad.returncode == 2
    assert "--wrench-frame 'ned': choose body or world" in bad.stderr
    assert "Traceback" not in bad.stderr
