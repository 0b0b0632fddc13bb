"""PoseStream validation: every repair counted, every rejection names the sample."""

from __future__ import annotations

import numpy as np
import pytest

from uwval.errors import PoseStreamError
from uwval.posestream import PoseStream


def _arrays(n: int = 4) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    t = np.arange(n, dtype=np.int64) * 10_000_000
    pos = np.arange(n * 3, dtype=np.float64).reshape(n, 3)
    quat = np.tile([0.0, 0.0, 0.0, 1.0], (n, 1))
    return t, pos, quat


def test_sorts_and_counts() -> None:
    t, p, q = _arrays()
    s = PoseStream.from_arrays(t[::-1], p[::-1], q, topic="/a", source="f.mcap")
    assert list(s.t) == sorted(t)
    np.testing.assert_array_equal(s.position, p)
    assert s.repairs["sorted"] == 3


def test_duplicates_dropped_or_rejected() -> None:
    t, p, q = _arrays()
    t[2] = t[1]
    s = PoseStream.from_arrays(t, p, q)
    assert len(s) == 3 and s.repairs["duplicates_dropped"] == 1
    with pytest.raises(PoseStreamError, match="duplicate stamp"):
        PoseStream.from_arrays(t, p, q, duplicates="error")


def test_nan_rejected_naming_sample() -> None:
    t, p, q = _arrays()
    p[2, 1] = np.nan
    with pytest.raises(PoseStreamError, match=r"f.mcap \[/x\]: sample 2"):
        PoseStream.from_arrays(t, p, q, topic="/x", source="f.mcap")


def test_quaternion_normalised_within_tolerance_rejected_beyond() -> None:
    t, p, q = _arrays()
    q[1] *= 1.001
    s = PoseStream.from_arrays(t, p, q)
    assert s.repairs["renormalized"] == 1
    np.testing.assert_allclose(np.linalg.norm(s.orientation, axis=1), 1.0)
    q[1] *= 2
    with pytest.raises(PoseStreamError, match="norm"):
        PoseStream.from_arrays(t, p, q)


def test_empty_and_shape_errors() -> None:
    with pytest.raises(PoseStreamError, match="N = 0"):
        PoseStream.from_arrays(np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros((0, 4)))
    t, p, q = _arrays()
    with pytest.raises(PoseStreamError, match="position"):
        PoseStream.from_arrays(t, p[:, :2], q)


def test_float_seconds_accepted() -> None:
    t, p, q = _arrays()
    s = PoseStream.from_arrays(t * 1e-9, p, q)
    np.testing.assert_array_equal(s.t, t)
    assert s.duration == pytest.approx(0.03)


def test_direct_construction_requires_increasing() -> None:
    t, p, q = _arrays()
    with pytest.raises(PoseStreamError, match="strictly increasing"):
        PoseStream(t=t[::-1].copy(), position=p, orientation=q)
