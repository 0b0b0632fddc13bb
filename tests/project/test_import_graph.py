"""The import graph of uwval: no circles, and no arrow from the core into the outer parts.

Every ``import`` statement counts, at module level or inside a function (a lazy import is
still a dependency). An import of a package's own ancestors (``uwval.bridge`` from
``uwval.bridge.session``) is not an arrow between modules and is left out.
"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
#: Where each part of the one ``uwval`` namespace lives in the checkout (pyproject package-dir).
PARTS = {
    "uwval": ROOT / "uwval",
    "uwval.simulator": ROOT / "simulator",
    "uwval.bridge": ROOT / "bridge",
    "uwval.reports": ROOT / "reports",
}
OUTER = ("uwval.simulator", "uwval.bridge", "uwval.reports", "uwval.cli")


def _modules() -> dict[str, Path]:
    out: dict[str, Path] = {}
    for pkg, folder in PARTS.items():
        for f in folder.rglob("*.py"):
            rel = f.relative_to(folder).with_suffix("")
            parts = [p for p in rel.parts if p != "__init__"]
            name = ".".join([pkg, *parts])
            if pkg == "uwval" and name.startswith(OUTER[:3]):
                continue
            out[name] = f
    return out


def _graph() -> dict[str, set[str]]:
    mods = _modules()
    graph: dict[str, set[str]] = {m: set() for m in mods}
    for name, path in mods.items():
        is_pkg = path.name == "__init__.py"
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            targets: list[str] = []
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:
                    pkg = name if is_pkg else name.rpartition(".")[0]
                    for _ in range(node.level - 1):
                        pkg = pkg.rpartition(".")[0]
                    base = f"{pkg}.{base}" if base else pkg
                targets = [f"{base}.{a.name}" for a in node.names] + [base]
            for t in targets:
                # the deepest known module the name points into
                while t and t not in mods:
                    t = t.rpartition(".")[0]
                if t and t != name and not name.startswith(t + "."):
                    graph[name].add(t)
    return graph


def _cycle(graph: dict[str, set[str]]) -> list[str] | None:
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(m: str) -> list[str] | None:
        state[m] = 1
        stack.append(m)
        for n in sorted(graph[m]):
            if state.get(n) == 1:
                return [*stack[stack.index(n) :], n]
            if n not in state and (found := visit(n)):
                return found
        stack.pop()
        state[m] = 2
        return None

    for m in sorted(graph):
        if m not in state and (found := visit(m)):
            return found
    return None


def test_the_vehicle_readers_do_not_import_each_other() -> None:
    g = _graph()
    assert "uwval.simulator.sdf" not in g["uwval.simulator.vehicle"]
    assert "uwval.simulator.vehicle" in g["uwval.simulator.sdf"]


def test_no_import_circle() -> None:
    assert _cycle(_graph()) is None


def test_the_cycle_finder_finds_one() -> None:
    assert _cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]


def test_the_core_imports_none_of_the_outer_parts() -> None:
    g = _graph()
    for m, deps in g.items():
        if m.startswith(OUTER) or m == "uwval.__main__":  # the entry point runs the CLI
            continue
        assert not {d for d in deps if d.startswith(OUTER)}, m


def test_the_error_classes_live_with_their_parts() -> None:
    import uwval.errors
    from uwval.bridge.errors import BridgeError
    from uwval.simulator.errors import SimulationError

    assert issubclass(SimulationError, uwval.errors.UwvalError)
    assert issubclass(BridgeError, uwval.errors.UwvalError)
    assert not hasattr(uwval.errors, "SimulationError")
    assert not hasattr(uwval.errors, "BridgeError")


def test_mypy_checks_every_part_under_its_installed_name() -> None:
    # pyproject's [tool.mypy] files reach simulator/, bridge/, reports/ through .mypy-layout
    import sys

    if sys.version_info >= (3, 11):
        import tomllib
    else:  # pragma: no cover - Python 3.10
        import tomli as tomllib

    cfg = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["mypy"]
    assert cfg["mypy_path"] == ".mypy-layout"
    for pkg, folder in PARTS.items():
        if pkg == "uwval":
            assert "uwval" in cfg["files"]
            continue
        link = ROOT / ".mypy-layout" / Path(*pkg.split("."))
        assert link.resolve() == folder.resolve(), pkg
        assert str(link.relative_to(ROOT)) in cfg["files"], pkg
