"""The C build of the physics kernel (uwval.simulator.ckernel) gives the Python kernel's numbers
bit for bit, for every kernel structure, and the stream uses it (issue 15: simulate an hour
fast). Skipped where no C compiler builds it (then the Python kernel runs)."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from uwval.simulator import SimulationStream, Simulator, constant_inputs, load_vehicle
from uwval.simulator.ckernel import c_source, compiled_kernel
from uwval.simulator.dynamics import generate_kernel_source
from uwval.simulator.errors import SimulationError
from uwval.simulator.inputs import InputProfile, PulseTrain, Ramp, Step
from uwval.simulator.presets import vehicles_dir

pytestmark = pytest.mark.skipif(
    compiled_kernel(generate_kernel_source(Simulator(load_vehicle("tethys"))._params.structure))
    is None,
    reason="no C compiler: the Python kernel runs",
)

VARYING = InputProfile(
    force=Ramp(end=np.array([25.0, -4.0, 3.0]), t0=0.1, t1=2.0),
    torque=PulseTrain(amplitude=np.array([0.5, -0.3, 1.5]), period=0.7, duty=0.4, t0=0.2),
    current=Step(after=np.array([0.3, -0.2, 0.05]), t0=1.1),
)

CASES: list[tuple[str, str, dict[str, Any], Any]] = [
    ("tethys still", "tethys", {}, constant_inputs()),
    (
        "tethys force torque current",
        "tethys",
        {},
        constant_inputs((10, 0, 0), (0, 0, 1), (0, 0.2, 0)),
    ),
    ("tethys varying inputs", "tethys", {}, VARYING),
    ("tethys implicit added mass", "tethys", {"implicit_added_mass": True}, VARYING),
    ("tethys legacy coriolis", "tethys", {"legacy_coriolis": True}, VARYING),
    ("tethys legacy gz8 (int abs)", "tethys", {"legacy_gz8": True}, VARYING),
    ("tethys fossen coriolis", "tethys", {"fossen_coriolis": True}, VARYING),
    (
        "tethys world wrench",
        "tethys",
        {},
        constant_inputs((5, 2, 0), (0, 0.5, 1), (0.1, 0, 0), wrench_frame="world"),
    ),
    ("bluerov2 heavy implicit", "bluerov2_heavy", {"implicit_added_mass": True}, VARYING),
    ("bluerov2 heavy stable", "bluerov2_heavy_stable", {}, VARYING),
    ("tethys from its SDF", str(vehicles_dir() / "tethys_sdf"), {}, VARYING),
]


def python_rows(sim: Simulator, ticks: int) -> np.ndarray:
    rec: list[Any] = []
    sim.advance_steps(ticks * sim.publish_every, rec)
    return np.asarray(rec, dtype=np.float64)


@pytest.mark.parametrize(
    ("vehicle", "kw", "inputs"), [c[1:] for c in CASES], ids=[c[0] for c in CASES]
)
def test_compiled_kernel_steps_the_python_kernels_numbers(
    vehicle: str, kw: dict[str, Any], inputs: Any
) -> None:
    """Ticks at 50 Hz over 3 s, across input-chunk boundaries (2000 steps), in two calls:
    every state value of every tick identical (array_equal, no tolerance)."""
    ref = Simulator(load_vehicle(vehicle), inputs, **kw)
    fast = Simulator(load_vehicle(vehicle), inputs, **kw)
    want = np.concatenate([python_rows(ref, 70), python_rows(ref, 80)])
    a = fast.advance_ticks_compiled(70)
    b = fast.advance_ticks_compiled(80)
    assert a is not None and b is not None
    got = np.concatenate([a, b])
    assert got.shape == want.shape == (151, 19)
    np.testing.assert_array_equal(got, want)
    assert fast.step == ref.step and fast.state == ref.state
    assert np.any(got[-1, 7:13] != 0.0) or inputs is CASES[0][3]


def test_a_diverging_run_fails_the_same_way() -> None:
    """Gazebo's explicit added mass on the published BlueROV2 Heavy diverges: the compiled
    path raises the Python path's error, at the same tick, naming the same twist."""
    inputs = constant_inputs((20, 0, 0), (0, 0, 2))
    errors = []
    for compiled in (False, True):
        sim = Simulator(load_vehicle("bluerov2_heavy"), inputs)

        def run(sim: Simulator = sim, compiled: bool = compiled) -> None:
            for _ in range(200):
                if compiled:
                    assert sim.advance_ticks_compiled(10) is not None
                else:
                    python_rows(sim, 10)

        with pytest.raises(SimulationError) as info:
            run()
        errors.append((str(info.value), sim.step))
    assert errors[0] == errors[1]
    assert "diverged" in errors[0][0]


def test_stream_uses_it_and_gives_the_same_chunks() -> None:
    v = load_vehicle("tethys")
    inputs = constant_inputs((10, 0, 0), (0, 0, 1), (0, 0.2, 0))
    fast = SimulationStream(v, inputs, 30.0, chunk_ticks=400, background=False)
    slow = SimulationStream(v, inputs, 30.0, chunk_ticks=400, background=False, compiled=False)
    assert fast.compiled and not slow.compiled
    assert not SimulationStream(v, inputs, 3600.0).background  # no child process needed
    for a, b in zip(fast, slow, strict=True):
        for name in ("t", "position", "orientation", "camera_position", "camera_orientation"):
            np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    assert fast.info["steps"] == slow.info["steps"] == 30_000


def test_without_the_accelerator_the_python_kernel_runs(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("UWVAL_NO_ACCELERATOR", "1")
    src = generate_kernel_source(Simulator(load_vehicle("tethys"))._params.structure)
    assert compiled_kernel(src) is None
    sim = Simulator(load_vehicle("tethys"))
    assert sim.advance_ticks_compiled(5) is None and sim.step == 0
    assert not SimulationStream(load_vehicle("tethys"), None, 1.0).compiled


def test_translation_keeps_python_semantics_in_c() -> None:
    """The C text: IEEE-exact operations in the Python source's order; CPython's floor
    division and pow; an unknown construct is refused (the Python kernel then runs)."""
    from uwval.simulator.ckernel import TranslationError

    src, params = c_source(
        "def kernel(n, k0, S, P, FX, FY, FZ, TX, TY, TZ, CX, CY, CZ):\n"
        "    a = P['a']\n"
        "    (x, y) = S\n"
        "    for k in range(k0, k0 + n):\n"
        "        x = a*x + FX[k] - y*2.0; y = (abs(x) // 1.0)**-0.5\n"
        "    return (x, y)\n"
    )
    assert params == ["a"]
    assert "x = (((a * x) + FX[k]) - (y * 2.0));" in src
    assert "y = pow(py_floordiv(fabs(x), 1.0), (-0.5));" in src
    with pytest.raises(TranslationError):
        c_source("def kernel(n, k0, S, P):\n    (x,) = S\n    x = max(x, 1.0)\n    return (x,)\n")
