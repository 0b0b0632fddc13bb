"""The compare fast path parses exactly the options typer declares (no drift)."""

from __future__ import annotations

import typer.main

from uwval.cli import app
from uwval.cli.compare_run import _FAST_OPTIONS, fast_compare


def _compare_params() -> dict[str, str]:
    import uwval.cli.compare_cmd  # noqa: F401  (registers the command)

    group = typer.main.get_command(app)
    cmd = group.commands["compare"]  # type: ignore[attr-defined]
    out = {}
    for p in cmd.params:
        for opt in getattr(p, "opts", []):
            if opt.startswith("-"):
                out[opt] = p.name
    return out


def test_every_fast_option_is_a_typer_option_with_the_same_destination() -> None:
    params = _compare_params()
    for opt, (dest, _) in _FAST_OPTIONS.items():
        assert params.get(opt) == dest, opt


def test_every_value_option_of_compare_is_known_to_the_fast_path_or_declined() -> None:
    params = _compare_params()
    declined = {"--batch", "--help", "--executor", "--workers", "--scheduler", "--allow-protocol"}
    for opt in params:
        if opt == "--json":
            continue
        if opt in declined:  # typer must handle these: the fast path declines, runs nothing
            assert fast_compare(["missing.mcap", opt, "2"]) is False
            continue
        assert opt in _FAST_OPTIONS, f"{opt} added to compare but not to the fast path"


def test_error_messages_with_brackets_are_printed_verbatim(tmp_path: object) -> None:
    import subprocess
    import sys

    res = subprocess.run(
        [
            sys.executable,
            "-m",
            "uwval",
            "simulate",
            "--vehicle",
            "[/x].toml",
            "--duration",
            "1",
            "-o",
            "/tmp/never.mcap",
        ],
        capture_output=True,
        text=True,
        timeout=60,
        stdin=subprocess.DEVNULL,
    )
    assert res.returncode == 2
    assert "Traceback" not in res.stderr
    assert "[/x].toml" in res.stderr


def test_io_names_resolve_lazily_and_match_all() -> None:
    import uwval.io as io_pkg

    assert sorted(io_pkg.__all__) == sorted(io_pkg._HOME)
    for name in io_pkg.__all__:
        assert getattr(io_pkg, name) is not None


def test_the_command_line_loads_numpy_only_after_it_chose_the_blas_threads(
    tmp_path: object,
) -> None:
    # `import uwval.cli` must not import numpy: main() sets OPENBLAS_NUM_THREADS for a
    # compare before numpy (and OpenBLAS's thread pool) loads; a user's own setting wins
    import subprocess
    import sys

    probe = (
        "import os, sys, uwval, uwval.cli\n"
        "assert 'numpy' not in sys.modules, 'numpy imported by uwval.cli'\n"
        "from uwval.cli import compare_run\n"
        "compare_run.fast_compare = lambda argv: True  # the compare itself is not needed\n"
        "os._exit = lambda code: print(os.environ.get('OPENBLAS_NUM_THREADS'))\n"
        "sys.argv = ['uwval', 'compare', 'a.tum', 'b.tum']\n"
        "uwval.cli.main()\n"
    )
    for env_value, expected in ((None, "1"), ("3", "3")):
        import os

        env = {k: v for k, v in os.environ.items() if k != "OPENBLAS_NUM_THREADS"}
        if env_value is not None:
            env["OPENBLAS_NUM_THREADS"] = env_value
        res = subprocess.run(
            [sys.executable, "-c", probe],
            capture_output=True,
            text=True,
            timeout=60,
            env=env,
            stdin=subprocess.DEVNULL,
        )
        assert res.returncode == 0, res.stderr
        assert res.stdout.strip() == expected
    import uwval

    assert uwval.PoseStream.__name__ == "PoseStream"  # still there, loaded on first use


def test_compare_with_stdout_closed_writes_its_file_and_exits_0(tmp_path: object) -> None:
    # cron jobs and daemons may start the command with fd 1 closed (sys.stdout is None)
    import os
    import subprocess
    import sys
    from pathlib import Path

    import numpy as np

    from uwval.io.tum import write_tum
    from uwval.posestream import PoseStream
    from uwval.rotations import quat_from_rpy

    d = Path(str(tmp_path))
    n = 200
    s = PoseStream.from_arrays(
        np.arange(n, dtype=np.int64) * 10_000_000,
        np.random.default_rng(1).normal(size=(n, 3)),
        quat_from_rpy(np.zeros((n, 3))),
    )
    write_tum(d / "a.tum", s)
    write_tum(d / "b.tum", s.with_(position=s.position + 0.01))
    res = subprocess.run(
        [
            sys.executable,
            "-m",
            "uwval",
            "compare",
            str(d / "a.tum"),
            str(d / "b.tum"),
            "-o",
            str(d / "out.json"),
        ],
        preexec_fn=lambda: os.close(1),
        stderr=subprocess.PIPE,
        text=True,
        timeout=60,
        stdin=subprocess.DEVNULL,
    )
    assert res.returncode == 0, res.stderr
    assert '"n_samples": 200' in (d / "out.json").read_text()
