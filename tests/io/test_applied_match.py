"""Applied stamps: the shortcut for the usual log (stamps logged at the poses' own distinct
times, in order) gives what the general matching gives, on any times and decode outcomes."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from uwval.errors import LogReadError
from uwval.io.encode import encode_header
from uwval.io.raw import RawTopic
from uwval.io.reader import _applied, _match_applied


def _topic(times: np.ndarray, stamps: np.ndarray, bad: list[int]) -> RawTopic:
    rows = encode_header(stamps, "", "cdr").copy()
    for k in bad:
        rows[k % len(rows), 1] = 0  # not plain little-endian CDR: not decoded (dropped)
    n, w = rows.shape
    return RawTopic(
        "/unity/model_rov_pose/applied_stamp",
        "std_msgs/msg/Header",
        "cdr",
        log_time=times.astype(np.int64),
        buf=rows.reshape(-1),
        offset=np.arange(n, dtype=np.int64) * w,
        length=np.full(n, w, dtype=np.int64),
    )


@settings(max_examples=200, deadline=None)
@given(
    n=st.integers(1, 60),
    steps=st.lists(st.integers(0, 3), min_size=60, max_size=60),
    same=st.booleans(),
    shift=st.integers(-2, 2),
    bad=st.lists(st.integers(0, 59), max_size=2),
    seed=st.integers(0, 2**16),
)
def test_the_shortcut_answers_as_the_general_match(
    n: int, steps: list[int], same: bool, shift: int, bad: list[int], seed: int
) -> None:
    rng = np.random.default_rng(seed)
    pose_times = 1_000 + np.cumsum(np.array(steps[:n], dtype=np.int64))  # repeats possible
    comp_times = pose_times.copy() if same else pose_times + shift
    stamps = rng.integers(0, 2**40, size=n)
    comp = _topic(comp_times, stamps, bad)
    got = _applied(Path("log.mcap"), comp, pose_times)
    from uwval.io.decode import decode_poses

    try:
        hdr = decode_poses(comp, errors="drop")
    except LogReadError:  # not one stamp decodes: no stamps, and a warning saying so
        assert got[0] is None and "no applied stamp could be decoded" in got[1]
        return
    want = _match_applied(
        Path("log.mcap"), comp.name, comp.log_time, hdr.stamp, hdr.handled, pose_times
    )
    assert got[1] == want[1]
    assert (got[0] is None) == (want[0] is None)
    if got[0] is not None and want[0] is not None:
        np.testing.assert_array_equal(got[0], want[0])


def test_the_usual_log_takes_the_shortcut_with_each_pose_its_own_stamp() -> None:
    t = np.arange(5, dtype=np.int64) * 10
    stamps = np.array([7, 3, 9, 1, 5], dtype=np.int64)
    got, warning = _applied(Path("log.mcap"), _topic(t, stamps, []), t)
    assert warning == "" and got is not None
    np.testing.assert_array_equal(got, stamps)


def test_a_companion_whose_every_stamp_is_undecodable_is_a_warning_not_a_failed_read() -> None:
    """The poses are read without latency, and the warning names the topic and why (found by
    the property test above: one message, not decodable, raised from the whole read)."""
    t = np.arange(3, dtype=np.int64) * 10
    got, warning = _applied(Path("log.mcap"), _topic(t, np.array([7, 3, 9]), [0, 1, 2]), t)
    assert got is None
    assert "log.mcap [/unity/model_rov_pose/applied_stamp]: no applied stamp" in warning
    assert "cannot be decoded as std_msgs/msg/Header" in warning
