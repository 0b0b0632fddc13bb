"""Shared test fixtures: paths to the read-only shared data."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

TESTS = Path(__file__).resolve().parent
sys.path.insert(0, str(TESTS))  # module-level task helpers importable by worker processes

from shared_data import SHARED_DATA  # noqa: E402


@pytest.fixture
def shared_data() -> Path:
    """../shared/data (read-only: copy before modifying); skips when absent."""
    if not SHARED_DATA.exists():
        pytest.skip("shared data folder not present")
    return SHARED_DATA


# The real ROS-TCP-Endpoint fixture (skips, saying why, where it cannot run).
from ros_endpoint_peer import ros_endpoint  # noqa: E402, F401
