"""Where uwval's embedded defaults live (``data/``: vehicles, experiments, baselines)."""

from __future__ import annotations

from pathlib import Path

from uwval.errors import ConfigError

#: The repository's data/ folder (uwval is installed in editable/development mode).
DATA_DIR = Path(__file__).resolve().parent.parent / "data"


def data_path(*parts: str) -> Path:
    """Path of an embedded data file, e.g. ``data_path("experiments", "default.toml")``."""
    p = DATA_DIR.joinpath(*parts)
    if not p.exists():
        raise ConfigError(f"embedded data file {p} is missing (is uwval installed with -e?)")
    return p
