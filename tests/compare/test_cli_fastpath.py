"""The compare fast path parses exactly the options typer declares (no drift)."""

from __future__ import annotations

from pathlib import Path

import pytest
import typer.main

from uwval.cli import app
from uwval.cli.compare_run import _FAST_OPTIONS, COMPARE_OPTIONS, fast_compare


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


def test_the_typer_command_and_the_fast_parser_come_from_one_option_table() -> None:
    # one source of truth: every flag typer knows (but --help) is a row of COMPARE_OPTIONS,
    # with its destination and default, and the fast parser knows exactly the fast rows
    import inspect

    from uwval.cli.compare_cmd import compare_command

    params = _compare_params()
    table = {f: o for o in COMPARE_OPTIONS for f in o.flags}
    assert set(params) - {"--help"} == set(table)
    for flag, o in table.items():
        assert params[flag] == o.dest
    sig = inspect.signature(compare_command).parameters
    assert all(sig[o.dest].default == o.default for o in COMPARE_OPTIONS)
    assert set(_FAST_OPTIONS) == {f for o in COMPARE_OPTIONS if o.fast for f in o.flags}


def test_every_value_option_of_compare_is_known_to_the_fast_path_or_declined() -> None:
    params = _compare_params()
    declined = {"--help"} | {f for o in COMPARE_OPTIONS if not o.fast for f in o.flags}
    assert declined >= {"--batch", "--executor", "--workers", "--scheduler", "--allow-protocol"}
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


@pytest.mark.skipif(not Path("/dev/full").exists(), reason="needs /dev/full")
@pytest.mark.parametrize(
    "extra",
    [
        [],  # the fast path, table output (rich)
        ["--json"],  # the fast path, buffered JSON: fails only at the final flush
        ["--sync", "nearest", "--align", "se3", "--json"],
        ["--sync=nearest", "--batch"],  # declined by the fast path: typer's usage error
    ],
)
def test_output_to_a_full_device_is_a_one_line_error(tmp_path: Path, extra: list[str]) -> None:
    import subprocess
    import sys

    a, b = _tum_pair(tmp_path)
    with open("/dev/full", "w") as full:
        res = subprocess.run(
            [sys.executable, "-m", "uwval", "compare", str(a), str(b), *extra],
            stdout=full,
            stderr=subprocess.PIPE,
            text=True,
            timeout=120,
            stdin=subprocess.DEVNULL,
        )
    assert "Traceback" not in res.stderr
    assert "Exception ignored" not in res.stderr
    if "--batch" in extra:  # a usage error goes to stderr: exit 2 from typer, one message
        assert res.returncode == 2
        return
    assert res.returncode == 2, res.stderr
    assert res.stderr.strip().splitlines() == [
        "error: cannot write the output: No space left on device"
    ]


@pytest.mark.skipif(not Path("/dev/full").exists(), reason="needs /dev/full")
@pytest.mark.parametrize("args", [["--help"], ["inspect", "A"], ["compare", "--help"]])
def test_typer_commands_on_a_full_device_give_one_line(tmp_path: Path, args: list[str]) -> None:
    import subprocess
    import sys

    a, _ = _tum_pair(tmp_path)
    with open("/dev/full", "w") as full:
        res = subprocess.run(
            [sys.executable, "-m", "uwval", *[str(a) if x == "A" else x for x in args]],
            stdout=full,
            stderr=subprocess.PIPE,
            text=True,
            timeout=120,
            stdin=subprocess.DEVNULL,
        )
    assert res.returncode == 2, res.stderr
    assert res.stderr.strip().splitlines() == [
        "error: cannot write the output: No space left on device"
    ]


def _tum_pair(d: Path) -> tuple[Path, Path]:
    lines = [f"{i * 0.02:.6f} {i * 0.01} {0.1 * (i % 7)} 0 0 0 0 1" for i in range(100)]
    a, b = d / "a.tum", d / "b.tum"
    a.write_text("\n".join(lines) + "\n")
    b.write_text("\n".join(lines) + "\n")
    return a, b


def test_the_fast_exit_still_runs_the_atexit_handlers(tmp_path: Path) -> None:
    # the fast path ends with os._exit (no teardown); what registered for the exit (coverage
    # saving its data, a user's hook) must still run, without special cases
    import subprocess
    import sys

    a, b = _tum_pair(tmp_path)
    mark = tmp_path / "ran"
    probe = (
        "import atexit, sys\n"
        f"atexit.register(lambda: open({str(mark)!r}, 'w').write('x'))\n"
        f"sys.argv = ['uwval', 'compare', {str(a)!r}, {str(b)!r}, '--json']\n"
        "from uwval.cli import main\n"
        "main()\n"
        "raise SystemExit(7)  # not reached: main ends the process\n"
    )
    res = subprocess.run(
        [sys.executable, "-c", probe],
        capture_output=True,
        text=True,
        timeout=120,
        stdin=subprocess.DEVNULL,
    )
    assert res.returncode == 0, res.stderr
    assert '"n_samples": 100' in res.stdout
    assert mark.read_text() == "x"
