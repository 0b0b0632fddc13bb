"""``uwval rpe`` vs ``evo_rpe tum`` on a large TUM pair: whole-command time and peak RSS.

Run by hand (not part of ``python -m benchmarks``; evo_rpe takes tens of seconds per run)::

    python benchmarks/bench_rpe.py                 # 100,000 poses, 5 alternating runs
    python benchmarks/bench_rpe.py --n 20000 --reps 3 --flags "-r angle_deg -as"

The pair is generated (seeded): a smooth 100 Hz trajectory, written as TUM text with 6
decimals for positions and 5 for quaternions (as SLAM tools write them), the estimate with a
3 ms clock skew and noise. Both tools get the same files and the same flags; each command is
timed in a fresh process (``benchmarks.common.run_command``: wall time and the command's own
peak RSS), uwval and evo alternating, medians reported. Both results are checked to agree.
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import tempfile
import zipfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.common import median, python_cmd, run_command


def make_pair(directory: Path, n: int) -> tuple[Path, Path]:
    """Reference and estimate TUM files of ``n`` poses (quaternions with 5 decimals)."""
    from uwval.comparison.synthetic import vehicle_motion

    ref = vehicle_motion(n, rate_hz=100.0, seed=0, t0_ns=1_700_000_000_000_000_000)
    rng = np.random.default_rng(1)
    paths = []
    for name, dt_ns, noise in (("ref.txt", 0, 0.0), ("est.txt", 3_000_000, 0.01)):
        t = (ref.t + dt_ns) / 1e9
        pos = ref.position + rng.normal(0.0, noise, (n, 3)) if noise else ref.position
        path = directory / name
        with open(path, "w") as fh:
            fh.write("# timestamp tx ty tz qx qy qz qw\n")
            np.savetxt(
                fh,
                np.concatenate([t[:, None], pos, ref.orientation], axis=1),
                fmt=["%.6f"] + ["%.6f"] * 3 + ["%.5f"] * 4,
            )
        paths.append(path)
    return paths[0], paths[1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=100_000, help="poses per file")
    ap.add_argument("--reps", type=int, default=5, help="alternating runs per tool")
    ap.add_argument("--flags", default="", help="evo_rpe flags given to both tools")
    args = ap.parse_args()
    evo_rpe = shutil.which("evo_rpe") or str(Path(sys.executable).parent / "evo_rpe")
    flags = args.flags.split()
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        ref, est = make_pair(d, args.n)
        uw_json = d / "uwval.json"
        evo_zip = d / "evo.zip"
        uw_cmd = python_cmd("-m", "uwval", "rpe", str(ref), str(est), *flags, "-o", str(uw_json))
        evo_cmd = [evo_rpe, "tum", str(ref), str(est), *flags, "--no_warnings", "--silent"]
        evo_cmd += ["--save_results", str(evo_zip)]
        times: dict[str, list[float]] = {"uwval": [], "evo": []}
        rss: dict[str, list[float]] = {"uwval": [], "evo": []}
        for rep in range(args.reps):
            for name, cmd in (("uwval", uw_cmd), ("evo", evo_cmd)):
                if name == "evo":
                    evo_zip.unlink(missing_ok=True)
                wall, peak = run_command(cmd)
                times[name].append(wall)
                rss[name].append(peak)
            print(f"run {rep + 1}: uwval {times['uwval'][-1]:.3f} s, evo {times['evo'][-1]:.3f} s")
        ours = json.loads(uw_json.read_text())["stats"]
        with zipfile.ZipFile(evo_zip) as z:
            theirs = json.loads(z.read("stats.json"))
        worst = max(abs(ours[k] - theirs[k]) / max(1.0, abs(theirs[k])) for k in theirs)
    tu, te = median(times["uwval"]), median(times["evo"])
    print(f"uwval rpe vs evo_rpe, {args.n} poses, flags {args.flags or '(defaults)'}")
    print(f"whole command, median of {args.reps}: uwval {tu:.3f} s, evo_rpe {te:.3f} s", end="")
    print(f" ({te / tu:.1f}x)")
    mu, me = max(rss["uwval"]), max(rss["evo"])
    print(f"peak RSS, max over runs: uwval {mu:.1f} MiB, evo_rpe {me:.1f} MiB ({me / mu:.1f}x)")
    print(f"largest stat difference (relative for |v| > 1): {worst:.2e}")


if __name__ == "__main__":
    main()
