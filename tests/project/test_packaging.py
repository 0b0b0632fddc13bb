"""The package's shape: what pyproject installs, the arrows between its parts, the embedded data.

No circle and no arrow into the core: tests/test_import_graph.py.

The wheel is built here from a copy of the checkout (offline: no build isolation) and must be
pure Python; it is installed in fresh virtual environments by ``.ci/package-smoke`` (every
claimed Python, commands run from another folder); these tests keep the sources in a shape
that makes that work.
"""

from __future__ import annotations

import ast
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python 3.10
    import tomli as tomllib

REPO = Path(__file__).resolve().parents[2]
PYPROJECT = tomllib.loads((REPO / "pyproject.toml").read_text())
SETUPTOOLS = PYPROJECT["tool"]["setuptools"]
PACKAGE_DIR: dict[str, str] = SETUPTOOLS["package-dir"]


def _folder_of(package: str) -> Path:
    """The source folder of ``package`` under pyproject's package-dir mapping."""
    best = max((k for k in PACKAGE_DIR if package == k or package.startswith(k + ".")), key=len)
    rest = package[len(best) :].lstrip(".")
    return REPO / PACKAGE_DIR[best] / Path(*rest.split(".")) if rest else REPO / PACKAGE_DIR[best]


def _modules() -> dict[str, Path]:
    """Every installed module name -> its source file."""
    mods: dict[str, Path] = {}
    for package in SETUPTOOLS["packages"]:
        folder = _folder_of(package)
        for f in folder.glob("*.py"):
            mods[package if f.stem == "__init__" else f"{package}.{f.stem}"] = f
    return mods


def _imports(mods: dict[str, Path]) -> dict[str, set[str]]:
    """Module -> the uwval modules it imports (anywhere in the file, lazy imports included)."""

    def resolve(name: str) -> str:
        while name and name not in mods:
            name = name.rpartition(".")[0]
        return name

    graph: dict[str, set[str]] = {m: set() for m in mods}
    for m, f in mods.items():
        for node in ast.walk(ast.parse(f.read_text(encoding="utf-8"))):
            targets: list[str] = []
            if isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                targets = [f"{node.module}.{a.name}" for a in node.names]
            elif isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            for t in targets:
                if t.startswith("uwval"):
                    r = resolve(t)
                    if r and r != m and r in mods:
                        graph[m].add(r)
    return graph


def test_every_source_package_is_installed() -> None:
    """Each folder with an __init__.py under a mapped folder is in pyproject's package list,
    so the wheel does not silently lose a sub-package."""
    listed = set(SETUPTOOLS["packages"])
    found = set()
    for package, folder in PACKAGE_DIR.items():
        root = REPO / folder
        for init in root.rglob("__init__.py"):
            rel = init.parent.relative_to(root)
            if any(part.startswith((".", "_")) or part == "build" for part in rel.parts):
                continue
            name = ".".join([package, *rel.parts])
            # a folder that package-dir maps elsewhere (simulator/ is not uwval/simulator/)
            if name in PACKAGE_DIR and PACKAGE_DIR[name] != str(Path(folder, *rel.parts)):
                continue
            found.add(name)
    assert found == listed, (
        f"not listed: {sorted(found - listed)}; listed, absent: {sorted(listed - found)}"
    )


def test_package_data_covers_every_data_file() -> None:
    """Every file under data/ (and the report templates) is shipped as package data."""
    globs = SETUPTOOLS["package-data"]
    for package, patterns in globs.items():
        folder = _folder_of(package)
        shipped = {p for pat in patterns for p in folder.glob(pat)}
        assert shipped, f"{package}: package-data patterns {patterns} match nothing"
    data = _folder_of("uwval.data")
    data_files = {p for p in data.rglob("*") if p.is_file() and p.suffix not in (".py", ".pyc")}
    data_files = {p for p in data_files if "__pycache__" not in p.parts}
    shipped = {p for pat in globs["uwval.data"] for p in data.glob(pat)}
    assert data_files <= shipped, (
        f"data files not shipped: {sorted(map(str, data_files - shipped))}"
    )


def test_outer_parts_do_not_import_each_other() -> None:
    """simulator, bridge and reports use the core, never each other (the bridge may drive the
    simulator in a live run), and none of them imports the CLI."""
    graph = _imports(_modules())
    allowed = {("uwval.bridge", "uwval.simulator")}
    parts = ("uwval.simulator", "uwval.bridge", "uwval.reports")
    bad = []
    for m, targets in graph.items():
        home = next((p for p in parts if m == p or m.startswith(p + ".")), None)
        if home is None:
            continue
        for t in targets:
            other = next(
                (p for p in (*parts, "uwval.cli") if t == p or t.startswith(p + ".")), None
            )
            if other and other != home and (home, other) not in allowed:
                bad.append((m, t))
    assert not bad


def test_embedded_data_is_found_through_the_package() -> None:
    """The defaults come from the installed package ``uwval.data``, not a checkout path."""
    from uwval.resources import data_dir, data_path

    assert data_dir() == _folder_of("uwval.data").resolve() or data_dir().name == "data"
    assert data_path("experiments", "default.toml").is_file()
    from uwval.errors import ConfigError

    with pytest.raises(ConfigError, match="missing"):
        data_path("experiments", "no_such_file.toml")


def test_version_and_short_help() -> None:
    """``uwval --version`` prints the package version; ``-h`` is ``--help``."""
    import uwval

    out = subprocess.run(
        [sys.executable, "-m", "uwval", "--version"], capture_output=True, text=True, check=True
    )
    assert out.stdout.splitlines()[0] == f"uwval {uwval.__version__}"  # then the embedded defaults
    for args in (["-h"], ["compare", "-h"], ["simulate", "-h"]):
        res = subprocess.run(
            [sys.executable, "-m", "uwval", *args], capture_output=True, text=True, check=False
        )
        assert res.returncode == 0, res.stderr
        assert "Usage" in res.stdout


def test_bench_outside_a_checkout_says_it_needs_one(tmp_path: Path) -> None:
    """``uwval bench`` from a folder that is no checkout, with no editable checkout to fall
    back on, refuses in one line (the benchmarks are not part of the wheel)."""
    from uwval.cli.bench_cmd import find_checkout

    assert find_checkout(REPO / "tests") == REPO
    # From tmp_path the search ends at the editable checkout (this test suite's): the
    # wheel-only case, with no checkout at all, is run by .ci/package-smoke.
    found = find_checkout(tmp_path)
    assert found is None or (found / "benchmarks" / "__main__.py").is_file()


def _tracked_copy(dest: Path) -> Path:
    """The checkout's tracked files copied to ``dest`` (a build writes build/ and egg-info
    beside its sources: never into the checkout); every file when git is not there."""
    try:
        listed = subprocess.run(
            ["git", "ls-files", "-z"], cwd=REPO, capture_output=True, check=True
        ).stdout.decode()
        files = [f for f in listed.split("\0") if f and (REPO / f).is_file()]
    except (OSError, subprocess.CalledProcessError):
        skip = shutil.ignore_patterns(".*", "build", "*.egg-info", "__pycache__", "*.so")
        shutil.copytree(REPO, dest, ignore=skip)
        return dest
    for f in files:
        (dest / f).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(REPO / f, dest / f)
    return dest


def test_wheel_is_pure_python(tmp_path: Path) -> None:
    """The wheel built from the sources is ``py3-none-any`` and ships no C source or binary:
    nothing of uwval's own is compiled, at build time or at run time."""
    src = _tracked_copy(tmp_path / "src")
    out = tmp_path / "dist"
    res = subprocess.run(
        [sys.executable, "-m", "build", "--wheel", "--no-isolation", "-o", str(out), str(src)],
        capture_output=True,
        text=True,
        check=False,
    )
    assert res.returncode == 0, res.stdout[-2000:] + res.stderr[-2000:]
    (wheel,) = out.glob("*.whl")
    assert wheel.name.endswith("-py3-none-any.whl"), wheel.name
    names = zipfile.ZipFile(wheel).namelist()
    compiled = [n for n in names if n.endswith((".c", ".h", ".so", ".pyd", ".dylib", ".pyx"))]
    assert not compiled, compiled
    assert "uwval/io/tum.py" in names
    tags = zipfile.ZipFile(wheel).read(next(n for n in names if n.endswith("/WHEEL")))
    assert b"Root-Is-Purelib: true" in tags and b"Tag: py3-none-any" in tags
