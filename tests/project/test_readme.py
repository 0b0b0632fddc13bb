"""The README says what users type: every ``uwval`` command in its ``bash`` blocks runs, as
written, in document order, in a scratch folder holding a copy of ``data/`` (so commands that
write, e.g. ``--write-baseline data/baselines/default.json``, touch only the copy).

Commands that need something this machine does not have (a Dask cluster at a named address,
object stores) are listed in ``NOT_RUN`` with the reason; every other command must succeed.
Inline ``uwval ...`` mentions in the prose must name commands and options that exist.
"""

from __future__ import annotations

import re
import shlex
import shutil
from pathlib import Path

from cli_runner import run_uwval

REPO = Path(__file__).resolve().parents[2]
README = (REPO / "README.md").read_text(encoding="utf-8")

#: Commands shown in the README that cannot run here, each with why (matched by substring).
NOT_RUN = {
    "--scheduler tcp://scheduler:8786": "needs a Dask cluster at a named host",
    "uwval simulate big.toml": "an example of a user's own experiment file",
    "pip install": "installs the package (CI runs the quick start's install itself)",
    "python3 -m pytest": "the test suite itself",
}


def _bash_commands() -> list[str]:
    """The commands of the README's bash blocks, comments stripped, continuations joined."""
    commands: list[str] = []
    for block in re.findall(r"```bash\n(.*?)```", README, flags=re.S):
        text = block.replace("\\\n", " ")
        for line in text.splitlines():
            line = re.sub(r"\s+#.*$", "", line).strip()
            if line and not line.startswith("#"):
                commands.extend(part.strip() for part in line.split("&&"))
    return commands


def test_readme_shows_the_quick_start() -> None:
    """The two quick-start commands: install + demo, install + tests (what .ci/run runs)."""
    commands = _bash_commands()
    assert commands[:4] == [
        "pip install -e .",
        "uwval demo",
        'pip install -e ".[test]"',
        "python3 -m pytest",
    ]
    ci = (REPO / ".ci" / "run").read_text()
    assert 'pip install -q -e ".[test]"' in ci
    assert "python3 -m pytest" in ci


def test_every_readme_command_runs(tmp_path: Path) -> None:
    """Each uwval command of the bash blocks exits 0, in order, from a user's folder."""
    shutil.copytree(REPO / "data", tmp_path / "data", ignore=shutil.ignore_patterns("*.py"))
    ran = 0
    for command in _bash_commands():
        if any(key in command for key in NOT_RUN):
            continue
        argv = shlex.split(command)
        assert argv[0] == "uwval", f"README command not run by this test: {command!r}"
        res = run_uwval(*argv[1:], cwd=tmp_path, timeout=300)
        assert res.returncode == 0, f"README command failed: {command}\n{res.stdout}\n{res.stderr}"
        ran += 1
    assert ran >= 10


def _command_names() -> dict[str, set[str]]:
    """Each uwval command path (``compare``, ``bridge serve``) -> its option names, from --help."""
    from uwval.cli import _register, get_app

    _register(None)
    import typer.main

    group = typer.main.get_command(get_app())
    names: dict[str, set[str]] = {}

    def walk(cmd: object, path: str) -> None:
        params = getattr(cmd, "params", [])
        names[path] = {o for p in params for o in (*p.opts, *p.secondary_opts)}
        for sub_name, sub in getattr(cmd, "commands", {}).items():
            walk(sub, f"{path} {sub_name}".strip())

    walk(group, "")
    return names


def test_inline_commands_name_real_commands_and_options() -> None:
    """Every ``uwval ...`` in backticks in the prose names an existing command, and every
    ``--option`` it shows is one of that command's options."""
    known = _command_names()
    spans = re.findall(r"`(uwval [^`]+)`", README)
    spans += _bash_commands()
    checked = 0
    for span in spans:
        if not span.startswith("uwval "):
            continue
        for command in span.split("&&"):
            words = shlex.split(command.strip())
            if not words or words[0] != "uwval":
                continue
            path = ""
            for w in words[1:]:
                candidate = f"{path} {w}".strip()
                if candidate in known:
                    path = candidate
                else:
                    break
            assert path or words[1:2] in (["--version"], ["-h"], ["--help"]), span
            options = {w.split("=")[0] for w in words if w.startswith("--")}
            unknown = options - known.get(path, set()) - {"--help"}
            assert not unknown, f"README: `{span}` shows {sorted(unknown)}, not options of {path!r}"
            checked += 1
    assert checked >= 20


def test_documented_write_formats_are_accepted(tmp_path: Path) -> None:
    """Each ``--format`` value the README documents for writing is accepted by simulate."""
    m = re.search(r"Write: (.*?)\.\n", README, flags=re.S)
    assert m, "README lists no write formats"
    formats = re.findall(r"`--format (\S+)`|`(\S+?)`", m.group(1))
    values = [a or b for a, b in formats]
    assert "mcap" in values and "rosbag2-mcap" in values
    for fmt in values:
        res = run_uwval(
            "simulate", "--duration", "0.5", "--format", fmt, "-o", tmp_path / f"run-{fmt}"
        )
        assert res.returncode == 0, f"--format {fmt}: {res.stderr}"


def test_python_snippets_compile() -> None:
    """The README's Python examples are valid Python."""
    for block in re.findall(r"```python\n(.*?)```", README, flags=re.S):
        compile(block, "README.md", "exec")
