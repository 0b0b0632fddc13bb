"""Where ../shared/data lies (read-only: copy before modifying), found upward from the tests so
that a worktree one level deeper finds it too; tests that need it skip, saying why, without."""

from __future__ import annotations

from pathlib import Path

import pytest

SHARED_DATA = next(
    (
        p / "shared" / "data"
        for p in Path(__file__).resolve().parents
        if (p / "shared" / "data").is_dir()
    ),
    Path("shared-data-not-found"),
)
#: evo's TUM example pairs
EVO_DATA = SHARED_DATA / "evo"


def shared(*parts: str) -> Path:
    """SHARED_DATA/<parts>, or a skip that says the shared data is not present."""
    path = SHARED_DATA.joinpath(*parts)
    if not path.exists():
        pytest.skip(f"shared data not present ({path})")
    return path
