"""Simulator speed: one vehicle's real-time factor at 1 ms steps, and batched vehicle-steps/s.

Targets (issue 5): RTF >= 200 for one vehicle (a 60 s run in < 0.3 s), >= 1M vehicle-steps/s
for a batched sweep on one core. Run: ``python -m benchmarks.bench_sim`` (``--quick``).
"""

from __future__ import annotations

import sys

from benchmarks.common import BenchRow, alternate, median
from uwval.resources import data_path
from uwval.simulator import constant_inputs, load_experiment, load_vehicle, simulate, simulate_batch


def run(quick: bool = False) -> list[BenchRow]:
    """Measure and return the simulator's rows."""
    reps = 3 if quick else 5
    tethys = load_vehicle("tethys")
    duration = 20.0 if quick else 60.0
    full = constant_inputs(force=(10, 0, 0), torque=(0, 0, 1), current=(0, 0.2, 0))
    still = constant_inputs(force=(10, 0, 0))
    simulate(tethys, full, 1.0)  # compile the kernels once
    simulate(tethys, still, 1.0)
    t_full, t_still = alternate(
        [lambda: simulate(tethys, full, duration), lambda: simulate(tethys, still, duration)],
        reps,
    )
    rows = []
    for label, times in (("force+torque+current", t_full), ("force only", t_still)):
        rtf = duration / median(times)
        rows.append(
            BenchRow(
                name=f"sim: one vehicle, 1 ms steps, {label}",
                uwval=rtf,
                unit="RTF",
                target=">= 200",
                met=rtf >= 200,
                notes=f"{duration:.0f} s in {median(times) * 1e3:.0f} ms, median of {reps}",
            )
        )
    n = 1000 if quick else 2000
    bdur = 2.0 if quick else 5.0
    vehicles = [tethys.with_params(xUabsU=-6.2282 * (1 + i / n)) for i in range(n)]
    inputs = [constant_inputs(force=(5 + 10 * i / n, 0, 0), current=(0, 0.2, 0)) for i in range(n)]
    simulate_batch(vehicles[:2], inputs[:2], 0.1)
    (t_batch,) = alternate([lambda: simulate_batch(vehicles, inputs, bdur)], max(2, reps - 2))
    steps = n * round(bdur * 1000) / median(t_batch)
    rows.append(
        BenchRow(
            name=f"sim: batched sweep, {n} vehicles",
            uwval=steps,
            unit="vehicle-steps/s",
            target=">= 1M",
            met=steps >= 1e6,
            notes=f"{n} x {bdur:.0f} s at 1 ms in {median(t_batch):.2f} s, one process",
        )
    )
    exp = load_experiment(data_path("experiments", "default.toml"))
    runs = exp.runs()

    def demo() -> None:
        for r in runs:
            simulate(r.vehicle, r.inputs, r.duration_s, **r.simulate_kwargs())

    (t_demo,) = alternate([demo], reps)
    rows.append(
        BenchRow(
            name="sim: default experiment physics (8 runs x 10 s, sequential)",
            uwval=median(t_demo),
            unit="s",
            notes="physics only; the demo adds bridge, recording and comparison",
        )
    )
    rows += whole_simulate(600.0 if quick else 3600.0, 1 if quick else 3)
    return rows


#: ``uwval simulate --duration 3600`` before issue 15 (whole run held in memory), idle machine.
SIMULATE_HOUR_BEFORE_S = 79.0


def whole_simulate(duration_s: float, reps: int) -> list[BenchRow]:
    """``uwval simulate --duration D`` as a user runs it: wall time and peak RSS (wait4's
    figure: the largest process of the command's tree, the physics child included).
    Targets for an hour: < 250 MiB, >= 5x faster than 79 s."""
    import tempfile
    from pathlib import Path

    from benchmarks.bench_shapes import _exe
    from benchmarks.common import run_command

    with tempfile.TemporaryDirectory() as d:
        out = Path(d) / "run.mcap"
        cmd = [_exe("uwval"), "simulate", "--duration", f"{duration_s:g}", "-o", str(out)]
        runs = [run_command(cmd) for _ in range(reps)]
    t = median([r[0] for r in runs])
    m = max(r[1] for r in runs)
    hour = duration_s >= 3600
    return [
        BenchRow(
            f"uwval simulate --duration {duration_s:g} (50 Hz, bridged, MCAP), wall",
            t,
            "s",
            SIMULATE_HOUR_BEFORE_S if hour else None,
            "before issue 15 (79 s, idle)" if hour else "",
            ">= 5x faster than before" if hour else "",
            (SIMULATE_HOUR_BEFORE_S / t >= 5.0) if hour else None,
            notes=f"{reps} runs, median",
        ),
        BenchRow(
            f"uwval simulate --duration {duration_s:g}, peak RSS",
            m,
            "MiB",
            target="< 250 MiB",
            met=m < 250.0,
            notes="max over runs; physics streamed in chunks (a child process for long runs)",
        ),
    ]


if __name__ == "__main__":
    for row in run(quick="--quick" in sys.argv):
        print(
            f"{row.name}: {row.uwval:,.4g} {row.unit}  target {row.target or '-'}  "
            f"met={row.met}  {row.notes}"
        )
