"""The house's shape rules (issue 30): no function over 12 parameters or 150 lines outside
the tests, no C of our own, and nothing that compiles or loads native code at run time."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
PARTS = ("uwval", "simulator", "bridge", "reports")
MAX_PARAMS = 12
MAX_LINES = 150


def _sources() -> list[Path]:
    return sorted(p for part in PARTS for p in (ROOT / part).rglob("*.py"))


def _functions(path: Path) -> list[tuple[str, int, int, int]]:
    """(name, first line, parameter count, line count) of every function in ``path``."""
    tree = ast.parse(path.read_text(encoding="utf-8"), str(path))
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
            a = node.args
            params = [*a.posonlyargs, *a.args, *a.kwonlyargs]
            names = [p.arg for p in params if p.arg not in ("self", "cls")]
            count = len(names) + (a.vararg is not None) + (a.kwarg is not None)
            length = (node.end_lineno or node.lineno) - node.lineno + 1
            out.append((node.name, node.lineno, count, length))
    return out


def test_the_rule_counts_what_it_claims(tmp_path: Path) -> None:
    src = tmp_path / "m.py"
    body = "\n".join(f"    x{i} = {i}" for i in range(160))
    src.write_text(f"def f(self, a, b, *c, d, **e):\n{body}\n")
    [(name, line, params, length)] = _functions(src)
    assert (name, line, params, length) == ("f", 1, 5, 161)


@pytest.mark.parametrize("path", _sources(), ids=lambda p: str(p.relative_to(ROOT)))
def test_functions_are_small(path: Path) -> None:
    big = [
        f"{path.relative_to(ROOT)}:{line} {name}: {params} parameters, {length} lines"
        for name, line, params, length in _functions(path)
        if params > MAX_PARAMS or length > MAX_LINES
    ]
    assert not big, "\n".join(big)


def test_no_native_code_of_our_own() -> None:
    native = [
        p.relative_to(ROOT)
        for part in PARTS
        for ext in ("*.c", "*.h", "*.cc", "*.cpp", "*.pyx", "*.pyi")
        for p in (ROOT / part).rglob(ext)
    ]
    assert not native
    text = "\n".join(p.read_text(encoding="utf-8") for p in _sources())
    for needle in ("ctypes", "dlopen", "dlsym", "cffi", "ext-modules"):
        assert needle not in text, needle
    assert "ext-modules" not in (ROOT / "pyproject.toml").read_text()
