"""The README says what users type: every ``uwval`` command in its ``bash`` blocks runs, as
written, in document order, in a scratch folder outside the checkout (embedded defaults by
name), and so does every Python example.

Commands this test does not run (the demo, which its own test runs once; servers) are listed
in ``NOT_RUN`` with the reason; every other command must succeed. Inline
``uwval ...`` mentions in the prose must name commands and options that exist.
"""

from __future__ import annotations

import re
import shlex
import subprocess
import sys
from pathlib import Path

import numpy as np
from cli_runner import run_uwval

REPO = Path(__file__).resolve().parents[2]
README = (REPO / "README.md").read_text(encoding="utf-8")

#: Commands shown in the README that this test does not run, each with why (by substring).
NOT_RUN = {
    "uwval demo": "tests/project/test_demo.py runs the demo once",
    "uwval bridge serve": "a server that runs until stopped: tests/bridge run it on loopback",
    "uwval bridge unity": "needs a running endpoint: tests/bridge run it against one",
}

#: The quick start: install + demo, install + tests (the second is what .ci/run runs).
QUICK_START = [
    "python3 -m venv .venv && .venv/bin/pip install . && .venv/bin/uwval demo",
    'python3 -m venv .venv && .venv/bin/pip install -e ".[test]" && .venv/bin/python -m pytest',
]


def _blocks(kind: str) -> list[str]:
    return re.findall(rf"```{kind}\n(.*?)```", README, flags=re.S)


def _bash_commands() -> list[str]:
    """The commands of the README's bash blocks, comments stripped, continuations joined."""
    commands: list[str] = []
    for block in _blocks("bash"):
        text = block.replace("\\\n", " ")
        for line in text.splitlines():
            line = re.sub(r"\s+#.*$", "", line).strip()
            if line and not line.startswith("#"):
                commands.extend(part.strip() for part in line.split("&&"))
    return commands


def test_readme_shows_the_quick_start() -> None:
    """The first bash block is the two quick-start commands, and .ci/run runs the second."""
    first = [line for line in _blocks("bash")[0].splitlines() if line.strip()]
    assert first == QUICK_START
    ci = (REPO / ".ci" / "run").read_text().splitlines()
    runs = [line.split(" #")[0].replace(" -q", "").strip() for line in ci]
    for part in QUICK_START[1].split(" && "):
        assert any(line.startswith(part) for line in runs), part


def _tum_pair(folder: Path) -> None:
    """groundtruth.txt / estimate.txt: a smooth TUM pair, the estimate noisy and 5 ms late."""
    rng = np.random.default_rng(0)
    t = np.arange(0.0, 20.0, 0.05)
    gt = np.stack([np.cos(0.3 * t), np.sin(0.3 * t), 0.1 * t], axis=1)
    est = gt + rng.normal(0, 0.01, gt.shape)
    quat = np.tile([0.0, 0.0, 0.0, 1.0], (len(t), 1))
    for name, stamps, pos in (("groundtruth", t, gt), ("estimate", t + 0.005, est)):
        rows = np.column_stack([stamps, pos, quat])
        np.savetxt(folder / f"{name}.txt", rows, fmt="%.6f")


def test_every_readme_command_runs(tmp_path: Path) -> None:
    """Each uwval command of the bash blocks exits 0, in order, from a user's folder (not the
    checkout), and then each Python example runs there."""
    _tum_pair(tmp_path)
    ran = 0
    for command in _bash_commands():
        if not command.startswith("uwval ") or any(key in command for key in NOT_RUN):
            continue
        argv = shlex.split(command)
        res = run_uwval(*argv[1:], cwd=tmp_path, timeout=600)
        assert res.returncode == 0, f"README command failed: {command}\n{res.stdout}\n{res.stderr}"
        ran += 1
    assert ran >= 12
    for block in _blocks("python"):
        res = subprocess.run(
            [sys.executable, "-c", block],
            cwd=tmp_path,
            capture_output=True,
            text=True,
            timeout=600,
            stdin=subprocess.DEVNULL,
        )
        assert res.returncode == 0, f"README example failed:\n{block}\n{res.stderr[-3000:]}"


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
    assert checked >= 15


def test_docs_commands_name_real_commands_and_options() -> None:
    """The commands the docs/ pages show (in backticks and bash blocks) name existing
    commands, and only options those commands take."""
    known = _command_names()
    checked = 0
    for doc in sorted((REPO / "docs").glob("*.md")):
        text = doc.read_text(encoding="utf-8")
        spans = re.findall(r"`(uwval [^`]+)`", text)
        for block in re.findall(r"```bash\n(.*?)```", text, flags=re.S):
            spans += [re.sub(r"\s+#.*$", "", ln).strip() for ln in block.splitlines()]
        for span in spans:
            words = shlex.split(span) if span.startswith("uwval ") else []
            if len(words) < 2 or words[1] not in known:
                continue  # prose that begins with "uwval", or --version
            path = words[1]
            for w in words[2:]:
                if f"{path} {w}" not in known:
                    break
                path = f"{path} {w}"
            options = {w.split("=")[0] for w in words if w.startswith("--")}
            unknown = options - known[path] - {"--help"}
            assert not unknown, f"{doc.name}: `{span}` shows {sorted(unknown)}, not of {path!r}"
            checked += 1
    assert checked >= 40
