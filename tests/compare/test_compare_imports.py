"""A plain ``uwval compare`` loads only what it uses: start-up is most of a short compare
(benchmarks/README.md), so modules it does not need stay unloaded. Each one listed here was
once loaded by every compare and cost milliseconds (python -X importtime). typer, rich and
json are not listed: typer is the only command-line parser and rich prints every table;
nor is concurrent.futures: a log's two pose pairs are compared on the standard library's
thread pool (issue 30: no private pool)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

#: never loaded by a compare that prints its table (module: what loaded it, its cost)
NOT_LOADED = (
    "uwval.comparison.rpe",  # RPE code, for its relation names: ~2.5 ms
    "matplotlib",  # plots only with --plot
    "pandas",
)
# tempfile and shutil are not listed: typer's pydantic (2.14) loads importlib.metadata for its
# plugin entry points, and that loads both, whatever uwval does
#: never loaded by a compare of a single-file log (an MCAP file): rosbag2 directories only
NOT_LOADED_FOR_A_FILE = ("ruamel.yaml",)


def _loaded_at_start() -> set[str]:
    """What the interpreter has loaded before any code runs (its site hooks included: a
    site-wide .pth file may load modules a compare never asks for)."""
    code = "import sys; print(' '.join(sorted(sys.modules)))"
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True
    ).stdout
    return set(out.split())


def _loaded_after_compare(args: list[str]) -> set[str]:
    code = (
        "import sys\n"
        "from uwval.cli import main\n"
        "try:\n"
        f"    main({args!r})\n"
        "except SystemExit:\n"
        "    pass\n"
        "print(' '.join(sorted(sys.modules)))\n"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True
    ).stdout
    return set(out.strip().splitlines()[-1].split())


@pytest.mark.parametrize("fmt", ["mcap", "rosbag2", "rosbag2-mcap"])
def test_a_compare_of_a_log_does_not_load_what_it_does_not_use(tmp_path: Path, fmt: str) -> None:
    from uwval.comparison.synthetic import unity_view, vehicle_motion
    from uwval.io.writers import open_writer, write_stream

    vehicle = vehicle_motion(20_000, 100.0)  # long enough for the inflate and decode threads
    log = tmp_path / ("pair.mcap" if fmt == "mcap" else "pair")
    with open_writer(log, fmt) as w:
        write_stream(w, vehicle.topic, vehicle, "enu")
        unity = unity_view(vehicle)
        write_stream(w, unity.topic, unity, unity.frame)
    loaded = _loaded_after_compare(["compare", str(log), "--sync", "nearest"])
    assert "uwval.comparison.engine" in loaded  # the compare ran in this process
    added = loaded - _loaded_at_start()
    assert not [m for m in NOT_LOADED if m in added]
    if fmt == "mcap":
        assert not [m for m in NOT_LOADED_FOR_A_FILE if m in added]


def _blas_setting(env_value: str | None) -> tuple[str, str]:
    """What the command line leaves in OPENBLAS_NUM_THREADS, and whether numpy was loaded
    before it could set it, in a fresh interpreter (``env_value``: the user's own setting)."""
    import os

    env = {k: v for k, v in os.environ.items() if k not in ("OPENBLAS_NUM_THREADS",)}
    if env_value is not None:
        env["OPENBLAS_NUM_THREADS"] = env_value
    code = (
        "import os, sys\n"
        "import uwval.cli\n"
        "print(os.environ['OPENBLAS_NUM_THREADS'], 'numpy' in sys.modules)\n"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, env=env
    ).stdout.split()
    return out[0], out[1]


def test_the_command_line_runs_blas_on_one_thread_unless_the_user_chose() -> None:
    # one thread (OpenBLAS woke its threads for every vector product: ms a call on 2 cores),
    # set before numpy loads, and a user's own setting is kept
    assert _blas_setting(None) == ("1", "False")
    assert _blas_setting("3") == ("3", "False")


def test_a_compare_of_tum_text_does_not_load_pandas(tmp_path: Path) -> None:
    # TUM text goes through numpy's reader: pandas' import (0.2-0.3 s with pyarrow) made a
    # compare of a small TUM pair slower than evo_ape's (benchmarks/README.md, start-up rows)
    from uwval.comparison.synthetic import vehicle_motion
    from uwval.io.tum import write_tum

    vehicle = vehicle_motion(2_000, 100.0)
    write_tum(tmp_path / "a.tum", vehicle)
    write_tum(tmp_path / "b.tum", vehicle)
    loaded = _loaded_after_compare(
        ["compare", str(tmp_path / "a.tum"), str(tmp_path / "b.tum"), "--sync", "nearest"]
    )
    assert "uwval.comparison.engine" in loaded
    assert "pandas" not in loaded - _loaded_at_start()
