"""Issue 30: one name and one kind per option across commands, and commands declared from
option tables (uwval/cli/declare.py) rather than long signatures."""

from __future__ import annotations

import importlib
import inspect
from collections import defaultdict
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import typer
import typer.main
from cli_runner import run_uwval

from uwval.cli import COMMAND_MODULES, get_app
from uwval.cli import shared_options as shared
from uwval.cli.declare import REQUIRED, Arg, Opt, declare_signature, opt

#: Options whose keyword several commands use for things of their own, with why.
OWN_PER_COMMAND = {
    "output": "-o is what each command writes: the JSON result (compare, rpe, doctor, "
    "inspect), the log (simulate), the page (report), the demo folder, the bridge's log",
    "duration": "each live or simulated run has its own length (simulate 20 s; teleop and "
    "bridge serve 0 = until stopped; bridge unity 10 s)",
    "pdf": "report --pdf PATH writes a PDF; demo --pdf/--no-pdf switches the demo's PDF",
    "protocol": "the bridge subcommands' ROS protocol defaults differ by role",
    "verbose": "bridge's --verbose/--quiet is a log level; compare and rpe's -v is evo's",
    "gazebo_topic": "bridge unity subscribes to several topics (repeatable)",
    "unity_topic": "bridge unity publishes several topics (repeatable)",
}


def _commands() -> dict[str, Any]:
    """Every leaf command of ``uwval`` (click objects), by its full name."""
    for module in COMMAND_MODULES:
        importlib.import_module(module)
    root = typer.main.get_command(get_app())

    def walk(cmd: Any, path: list[str]) -> Iterator[tuple[str, Any]]:
        subs = getattr(cmd, "commands", None)
        if subs:
            for name, sub in subs.items():
                yield from walk(sub, [*path, name])
        else:
            yield " ".join(path), cmd

    return dict(walk(root, []))


def _kind(ptype: Any) -> tuple[tuple[str, Any], ...]:
    """A click parameter type as comparable data: its class and its settings (choices,
    bounds, path checks)."""
    return ((type(ptype).__name__, ""), *sorted((k, repr(v)) for k, v in vars(ptype).items()))


def _shape(param: Any) -> tuple[Any, ...]:
    """What must agree between commands: flags, kind (type, flag, repeatable), default."""
    return (
        tuple(param.opts),
        tuple(param.secondary_opts),
        _kind(param.type),
        param.is_flag,
        param.multiple,
        param.default,
    )


def test_an_option_has_one_shape_in_every_command() -> None:
    by_dest: dict[str, dict[str, tuple[Any, ...]]] = defaultdict(dict)
    for name, cmd in _commands().items():
        for param in cmd.params:
            if param.param_type_name == "option" and param.name != "help":
                by_dest[param.name][name] = _shape(param)
    shared_dests = [dest for dest, cmds in by_dest.items() if len(cmds) > 1]
    assert {"max_diff", "thresholds", "baseline", "as_json", "executor"} <= set(shared_dests)
    differing = {
        dest: cmds
        for dest, cmds in by_dest.items()
        if len(set(cmds.values())) > 1 and dest not in OWN_PER_COMMAND
    }
    assert not differing, differing


@pytest.mark.parametrize(
    "declared",
    [v for v in vars(shared).values() if isinstance(v, Opt)],
    ids=lambda o: o.dest,
)
def test_a_shared_option_is_the_same_in_every_command_that_takes_it(declared: Opt) -> None:
    takers = []
    for name, cmd in _commands().items():
        for param in cmd.params:
            if param.name == declared.dest and declared.dest not in OWN_PER_COMMAND:
                takers.append(name)
                assert tuple(param.opts) + tuple(param.secondary_opts) == declared.flags, name
                assert param.default == declared.default, name
                assert param.help == declared.help, name
    if declared.dest not in OWN_PER_COMMAND:
        assert len(takers) >= 2, f"{declared.dest} is shared but only {takers} take it"


def test_report_and_check_take_compare_options_as_compare_does() -> None:
    commands = _commands()
    for dest in ("max_diff", "offset", "align", "frame", "sync", "fmt", "config"):
        shapes = {
            name: _shape(p)
            for name in ("compare", "report", "check")
            for p in commands[name].params
            if p.name == dest
        }
        assert len(shapes) == 3 and len(set(shapes.values())) == 1, (dest, shapes)


def test_declare_signature_builds_what_typer_reads() -> None:
    def command(**kw: Any) -> None:
        """A test command."""
        print(sorted(kw.items()))

    items = (
        Arg("source", Path, "A file"),
        Arg("other", Path, "Another", default=None),
        opt("max_runs", int, 3, "Runs", "--max-runs", "-n"),
        Opt("tags", ("--tag",), list[str], None, "Tags"),
        Opt("limit", ("--limit",), int, 5, "At most", (("min", 0),)),
    )
    declare_signature(command, items, context=True)
    sig = inspect.signature(command)
    assert list(sig.parameters) == ["ctx", "source", "other", "max_runs", "tags", "limit"]
    assert sig.parameters["source"].default is REQUIRED
    assert sig.parameters["max_runs"].default == 3
    assert command.__annotations__["return"] is None
    app = typer.Typer()
    app.command()(command)
    cmd = typer.main.get_command(app)
    by_name = {p.name: p for p in cmd.params}
    assert by_name["max_runs"].opts == ["--max-runs", "-n"]
    assert by_name["tags"].multiple
    assert by_name["limit"].type.min == 0
    assert opt("max_gap", float, None, "Gap").flags == ("--max-gap",)


def test_report_and_check_refuse_bad_input_in_one_line(tmp_path: Path) -> None:
    missing = tmp_path / "nothing.mcap"
    out = run_uwval("check", missing, "--thresholds", "none")
    assert out.returncode == 2
    assert "needs --thresholds" in out.stderr and "Traceback" not in out.stderr
    out = run_uwval("report", missing, "--max-detail-runs", "-1")
    assert out.returncode == 2 and "Traceback" not in out.stderr
    assert "max-detail-runs" in out.stderr


def test_rpe_takes_the_shared_offset_in_seconds(tmp_path: Path, shared_data: Path) -> None:
    """rpe's --offset is compare's declaration (a string): seconds work under every
    spelling, 'auto' (compare's estimate) is refused in one line."""
    import json
    import shutil

    ref, est = (
        shutil.copy(shared_data / "evo" / name, tmp_path / name)
        for name in ("fr2_desk_groundtruth.txt", "fr2_desk_ORB.txt")
    )
    plain = run_uwval("rpe", "tum", ref, est, "--json")
    zero = run_uwval("rpe", "tum", ref, est, "--json", "--t_offset", "0")
    assert plain.returncode == 0 and zero.returncode == 0, plain.stderr + zero.stderr
    assert json.loads(plain.stdout) == json.loads(zero.stdout)
    shifted = run_uwval("rpe", "tum", ref, est, "--json", "--offset", "0.5")
    assert shifted.returncode == 0, shifted.stderr
    assert json.loads(shifted.stdout) != json.loads(plain.stdout)
    auto = run_uwval("rpe", "tum", ref, est, "--offset", "auto")
    assert auto.returncode == 2 and "Traceback" not in auto.stderr
    assert "--offset 'auto'" in auto.stderr and len(auto.stderr.strip().splitlines()) == 1
