"""The physics kernel compiled to C, when a C compiler is there: the same numbers, ~50x faster.

:func:`uwval.simulator.dynamics.generate_kernel_source` writes one Python function per kernel
structure (scalar arithmetic, one loop over steps). This module translates that function's
syntax tree into C statement by statement (every operation in the same order, on IEEE doubles,
compiled with ``-ffp-contract=off`` and without fast-math, so no fused multiply-add, no
reassociation), builds it once with the system's C compiler into a cache directory and loads
it with ctypes. Python's float semantics are kept where C's differ: ``x // y`` follows
CPython's floor division, ``x ** y`` is C's ``pow`` as CPython's float power calls it.
tests/test_sim_ckernel.py checks bit equality with the Python kernel for every structure
(added mass explicit/implicit, currents, legacy modes, world wrench, centre of buoyancy).

No compiler, a failed build or ``UWVAL_NO_ACCELERATOR=1``: :func:`compiled_kernel` returns None
and the Python kernel runs (the same numbers, slower). Cache: ``$UWVAL_CACHE_DIR`` or
``~/.cache/uwval``, ``kernels/<sha256 of the source, flags, compiler and machine>.so``.
"""

from __future__ import annotations

import ast
import ctypes
import hashlib
import os
import platform
import shutil
import subprocess
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

F64 = NDArray[np.float64]

#: Compiler flags: optimised, IEEE-exact (no contraction into FMA, no fast-math).
CFLAGS = ["-O2", "-fPIC", "-shared", "-ffp-contract=off", "-fno-fast-math", "-std=c99"]
_INPUTS = ("FX", "FY", "FZ", "TX", "TY", "TZ", "CX", "CY", "CZ")

_PRELUDE = """\
#include <math.h>
#include <string.h>

/* CPython's float floor division (Objects/floatobject.c, float_floor_div): the same result
   for every input, signed zeros and non-finite values included. */
static double py_floordiv(double vx, double wx) {
    double mod = fmod(vx, wx);
    double div = (vx - mod) / wx;
    double floordiv;
    if (mod) {
        if ((wx < 0) != (mod < 0)) {
            mod += wx;
            div -= 1.0;
        }
    }
    if (div) {
        floordiv = floor(div);
        if (div - floordiv > 0.5)
            floordiv += 1.0;
    } else {
        floordiv = copysign(0.0, vx / wx);
    }
    return floordiv;
}
"""

_ADVANCE = """
/* nticks publish ticks of pe steps each, from input row k0; after each tick the state is
   stored in rec (nticks x NS) and checked as Simulator._check does (|velocity| < limit, NaN
   fails). Returns the ticks done: nticks, or the tick (1-based) at which it diverged. */
long advance(long nticks, long pe, long k0, double *S, const double *P,
             const double *FX, const double *FY, const double *FZ,
             const double *TX, const double *TY, const double *TZ,
             const double *CX, const double *CY, const double *CZ,
             double *rec, double limit) {
    for (long t = 0; t < nticks; t++) {
        kernel(pe, k0 + t * pe, S, P, FX, FY, FZ, TX, TY, TZ, CX, CY, CZ);
        memcpy(rec + t * NS, S, NS * sizeof(double));
        for (int i = 7; i < 13; i++)
            if (!(fabs(S[i]) < limit))
                return t + 1;
    }
    return nticks;
}
"""


class TranslationError(ValueError):
    """The Python kernel uses a construct this translator does not know."""


class _Emitter:
    """Python kernel AST -> C source (the subset generate_kernel_source writes)."""

    def __init__(self) -> None:
        self.params: list[str] = []
        self.state: list[str] = []
        self.locals: list[str] = []

    def expr(self, node: ast.expr) -> str:
        if isinstance(node, ast.Constant) and isinstance(node.value, (int, float)):
            return repr(float(node.value)) if isinstance(node.value, float) else f"{node.value}"
        if isinstance(node, ast.Name):
            return node.id
        if isinstance(node, ast.UnaryOp) and isinstance(node.op, ast.USub):
            return f"(-{self.expr(node.operand)})"
        if isinstance(node, ast.BinOp):
            a, b = self.expr(node.left), self.expr(node.right)
            ops = {ast.Add: "+", ast.Sub: "-", ast.Mult: "*", ast.Div: "/"}
            for kind, sym in ops.items():
                if isinstance(node.op, kind):
                    return f"({a} {sym} {b})"
            if isinstance(node.op, ast.Pow):
                return f"pow({a}, {b})"
            if isinstance(node.op, ast.FloorDiv):
                return f"py_floordiv({a}, {b})"
        if (
            isinstance(node, ast.Call)
            and isinstance(node.func, ast.Name)
            and node.func.id == "abs"
            and len(node.args) == 1
            and not node.keywords
        ):
            return f"fabs({self.expr(node.args[0])})"
        if (
            isinstance(node, ast.Subscript)
            and isinstance(node.value, ast.Name)
            and node.value.id in _INPUTS
            and isinstance(node.slice, ast.Name)
        ):
            return f"{node.value.id}[{node.slice.id}]"
        raise TranslationError(f"kernel construct not translated: {ast.dump(node)[:120]}")

    def assign(self, node: ast.Assign) -> str:
        if len(node.targets) != 1 or not isinstance(node.targets[0], ast.Name):
            raise TranslationError(f"kernel assignment not translated: {ast.dump(node)[:120]}")
        name = node.targets[0].id
        if name not in self.locals and name not in self.state:
            self.locals.append(name)
        return f"{name} = {self.expr(node.value)};"

    def function(self, src: str) -> str:
        """The C text of ``kernel(n, k0, S, P, FX..CZ)`` for the Python kernel ``src``."""
        (fn,) = ast.parse(src).body
        if not isinstance(fn, ast.FunctionDef):
            raise TranslationError("the kernel source is not one function")
        body: list[str] = []
        for stmt in fn.body:
            if (
                isinstance(stmt, ast.Assign)
                and isinstance(stmt.value, ast.Subscript)
                and isinstance(stmt.value.value, ast.Name)
                and stmt.value.value.id == "P"
                and isinstance(stmt.targets[0], ast.Name)
            ):
                self.params.append(stmt.targets[0].id)
            elif isinstance(stmt, ast.Assign) and isinstance(stmt.targets[0], ast.Tuple):
                self.state = [e.id for e in stmt.targets[0].elts if isinstance(e, ast.Name)]
            elif isinstance(stmt, ast.For):
                loop = [self.assign(s) for s in stmt.body if isinstance(s, ast.Assign)]
                if len(loop) != len(stmt.body):
                    raise TranslationError("the kernel loop holds more than assignments")
                body.append("for (long k = k0; k < k0 + n; k++) {")
                body += [f"    {line}" for line in loop]
                body.append("}")
            elif isinstance(stmt, ast.Return):
                body += [f"S[{i}] = {name};" for i, name in enumerate(self.state)]
            else:
                raise TranslationError(f"kernel statement not translated: {ast.dump(stmt)[:120]}")
        head = [f"const double {p} = P[{i}];" for i, p in enumerate(self.params)]
        head += [f"double {s} = S[{i}];" for i, s in enumerate(self.state)]
        if self.locals:
            head.append("double " + ", ".join(self.locals) + ";")
        args = ", ".join(f"const double *{x}" for x in _INPUTS)
        lines = [
            f"#define NS {len(self.state)}",
            f"static void kernel(long n, long k0, double *S, const double *P, {args}) {{",
            *(f"    {line}" for line in head + body),
            "}",
        ]
        return "\n".join(lines) + "\n"


def c_source(py_src: str) -> tuple[str, list[str]]:
    """C translation unit for the Python kernel ``py_src``, and the parameter names in the
    order the C code reads them from its ``P`` array."""
    em = _Emitter()
    fn = em.function(py_src)
    return _PRELUDE + fn + _ADVANCE, em.params


def _cache_dir() -> Path:
    root = os.environ.get("UWVAL_CACHE_DIR") or os.path.join(
        os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache"),
        "uwval",
    )
    return Path(root) / "kernels"


def _build(src: str) -> Path | None:
    """The shared library of ``src`` (built once into the cache), or None."""
    cc = os.environ.get("CC") or shutil.which("cc") or shutil.which("gcc")
    if cc is None:
        return None
    # the source, the flags, the compiler and the machine: a cache shared across hosts or
    # compilers never hands one a library built for another
    ident = "\0".join([src, " ".join(CFLAGS), os.path.realpath(cc), platform.machine()])
    key = hashlib.sha256(ident.encode()).hexdigest()[:32]
    out = _cache_dir() / f"{key}.so"
    if out.exists():
        return out
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryDirectory(dir=out.parent) as d:
            c = Path(d) / "kernel.c"
            c.write_text(src)
            lib = Path(d) / "kernel.so"
            res = subprocess.run(
                [cc, *CFLAGS, "-o", str(lib), str(c), "-lm"],
                capture_output=True,
                timeout=120,
                check=False,
            )
            if res.returncode != 0 or not lib.exists():
                return None
            os.replace(lib, out)  # atomic: a concurrent build of the same key is harmless
    except (OSError, subprocess.SubprocessError):
        return None
    return out


#: ``advance(nticks, pe, k0, S, P, inputs (9, m), rec (nticks, NS), limit) -> ticks done``
AdvanceFn = Callable[[int, int, int, F64, F64, F64, F64, float], int]
_CACHE: dict[str, tuple[AdvanceFn, list[str]] | None] = {}


def compiled_kernel(py_src: str) -> tuple[AdvanceFn, list[str]] | None:
    """``(advance, parameter names)`` of the C build of the Python kernel ``py_src``, or None
    (no compiler, build failed, ``UWVAL_NO_ACCELERATOR=1``)."""
    if os.environ.get("UWVAL_NO_ACCELERATOR"):
        return None
    if py_src in _CACHE:
        return _CACHE[py_src]
    result: tuple[AdvanceFn, list[str]] | None = None
    try:
        src, params = c_source(py_src)
    except TranslationError:
        src, params = "", []
    lib_path = _build(src) if src else None
    if lib_path is not None:
        try:
            lib = ctypes.CDLL(str(lib_path))
            fn = lib.advance
        except OSError:
            fn = None
        if fn is not None:
            ptr = ctypes.POINTER(ctypes.c_double)
            fn.restype = ctypes.c_long
            fn.argtypes = [ctypes.c_long] * 3 + [ptr] * 12 + [ctypes.c_double]
            result = (_wrap(fn, ptr), params)
    _CACHE[py_src] = result
    return result


def _wrap(fn: Any, ptr: Any) -> AdvanceFn:
    def advance(
        nticks: int,
        pe: int,
        k0: int,
        state: F64,
        params: F64,
        inputs: F64,
        rec: F64,
        limit: float,
    ) -> int:
        """Step ``nticks`` ticks of ``pe`` steps in place on ``state`` (NS,); inputs (9, m)
        C-contiguous float64 from row ``k0``; the state after each tick into ``rec``."""
        cols = [inputs[i].ctypes.data_as(ptr) for i in range(9)]
        return int(
            fn(
                nticks,
                pe,
                k0,
                state.ctypes.data_as(ptr),
                params.ctypes.data_as(ptr),
                *cols,
                rec.ctypes.data_as(ptr),
                limit,
            )
        )

    return advance
