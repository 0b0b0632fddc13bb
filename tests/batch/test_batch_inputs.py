"""Batch compare inputs: finding a sweep's logs."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest
from cli_runner import run_uwval as _uwval

from uwval.batch import items_from


@pytest.fixture(scope="module")
def run_log(tmp_path_factory: pytest.TempPathFactory) -> Path:
    log = tmp_path_factory.mktemp("batch") / "run.mcap"
    res = _uwval("simulate", "--duration", "2", "-o", str(log))
    assert res.returncode == 0, res.stderr
    return log


def test_batch_finds_logs_in_folders_named_like_levels(tmp_path: Path, run_log: Path) -> None:
    for sub in ("force_1.5", "force_2"):
        (tmp_path / sub).mkdir()
        shutil.copy(run_log, tmp_path / sub / f"{sub}.mcap")
    names = sorted(i.name for i in items_from(tmp_path))
    assert names == ["force_1.5", "force_2"]
