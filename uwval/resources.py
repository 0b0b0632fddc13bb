"""Where uwval's embedded defaults live: the package data ``uwval.data`` (the repository's
``data/`` folder: vehicles, experiments, thresholds, baselines), found through
:mod:`importlib.resources`, so that an installed wheel works from any folder."""

from __future__ import annotations

from importlib.resources import files
from pathlib import Path

from uwval.errors import ConfigError


def data_dir() -> Path:
    """The folder of the embedded defaults (installed: ``site-packages/uwval/data``)."""
    root = files("uwval.data")
    # Wheels install unzipped, so the resources are real files; say so clearly if not.
    if not isinstance(root, Path):
        raise ConfigError(
            f"uwval's embedded data is not on the file system ({root}): "
            "install uwval from a wheel or a checkout, not from a zip archive"
        )
    return root


def data_path(*parts: str) -> Path:
    """Path of an embedded data file, e.g. ``data_path("experiments", "default.toml")``."""
    p = data_dir().joinpath(*parts)
    if not p.exists():
        raise ConfigError(
            f"embedded data file {'/'.join(parts)} is missing from {data_dir()} "
            "(a broken installation: reinstall uwval)"
        )
    return p
