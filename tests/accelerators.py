"""The optional C accelerators in tests: a test module that exercises one needs it built.

CI sets ``UWVAL_REQUIRE_ACCELERATOR`` (``.ci/run``): a missing module then fails the run
instead of skipping its tests (a compiler-less install still reads every log, by the numpy,
loadtxt or sqlite3 path the module replaces).
"""

from __future__ import annotations

import os

import pytest


def require_module(module: object, name: str) -> None:
    """Skip the calling test module when the accelerator ``name`` (``module`` is what its
    import gave, None when it was not built) is missing; fail instead under CI's
    ``UWVAL_REQUIRE_ACCELERATOR``."""
    if module is not None:
        return
    if os.environ.get("UWVAL_REQUIRE_ACCELERATOR"):
        pytest.fail(f"{name} was not built (UWVAL_REQUIRE_ACCELERATOR is set)", pytrace=False)
    pytest.skip(f"the C accelerator {name} is not built here", allow_module_level=True)
