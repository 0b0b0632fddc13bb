"""The io seam (issue 13): the format is decided in uwval.io.formats only; the stamp helpers
live in uwval.io.stamps (no parser needed to convert a stamp)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from uwval.errors import ConfigError, LogReadError
from uwval.io import formats, stamps


def test_is_tum_and_log_kind_agree(tmp_path: Path) -> None:
    for name, kind in [("a.tum", "tum"), ("a.TXT", "tum"), ("a.csv", "csv"), ("a.mcap", "mcap")]:
        p = tmp_path / name
        p.write_bytes(b"x")
        assert formats.log_kind(p) == kind
        assert formats.is_tum(p) == (kind == "tum")
    assert formats.is_tum(tmp_path / "a.mcap", "tum")
    with pytest.raises(ConfigError, match="--format 'rosbag2-mcap'"):
        formats.is_tum("x", "rosbag2-mcap")
    blob = tmp_path / "noext"
    blob.write_bytes(b"\x89MCAP0\r\n" + bytes(20))
    assert formats.log_kind(blob) == "mcap"
    with pytest.raises(LogReadError, match="no such file"):
        formats.log_kind(tmp_path / "missing.mcap")


def test_comparison_uses_the_one_format_table() -> None:
    import uwval.comparison.logs as logs

    assert logs.is_tum is formats.is_tum
    assert logs.INPUT_FORMATS is formats.INPUT_FORMATS


def test_stamp_helpers_equal_the_tum_readers() -> None:
    from uwval.io import tum

    rng = np.random.default_rng(3)
    s = np.concatenate([rng.uniform(0, 2e9, 1000), rng.uniform(-5, 5, 100), [0.0, 1e10]])
    np.testing.assert_array_equal(stamps.ns_from_seconds(s), tum.ns_from_seconds(s))
    ns = rng.integers(-(2**62), 2**62, 1000)
    np.testing.assert_array_equal(stamps.seconds_from_ns(ns), tum.seconds_from_ns(ns))
