"""The typed options of a comparison (uwval.comparison.options): unit conversions equal evo's
``change_unit``, offsets parse as the engine takes them, evo's positional shapes are read as
evo reads them, and the defaults follow the inputs (evo's association for trajectory files)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from uwval.cli.compare_args import compare_options, evo_bare_align, read_positionals
from uwval.comparison.options import (
    AlignmentMode,
    ApeUnit,
    ClockOffset,
    CompareInputs,
    CompareOptions,
    InputFormat,
    SyncMethod,
    TimeWindow,
    unit_factor,
)
from uwval.errors import ConfigError

LENGTHS = ("mm", "cm", "m", "km")
ANGLES = ("deg", "rad")


@settings(max_examples=60, deadline=None)
@given(
    st.sampled_from([(a, b) for group in (LENGTHS, ANGLES) for a in group for b in group]),
    st.lists(st.floats(0, 1e6, allow_nan=False), min_size=1, max_size=20),
)
def test_unit_factor_equals_evos_change_unit(pair: tuple[str, str], values: list[float]) -> None:
    metrics = pytest.importorskip("evo.core.metrics")
    source, target = pair
    ape = metrics.APE(metrics.PoseRelation.translation_part)
    ape.error = np.array(values)
    ape.unit = metrics.Unit(source)
    ape.change_unit(metrics.Unit(target))
    ours = np.array(values) * unit_factor(source, ApeUnit(target))
    np.testing.assert_allclose(ours, ape.error, rtol=1e-15, atol=0)


@pytest.mark.parametrize(("source", "target"), [("m", "deg"), ("rad", "mm"), ("none", "m")])
def test_unit_factor_refuses_what_evo_refuses(source: str, target: str) -> None:
    with pytest.raises(ConfigError, match="cannot be given in"):
        unit_factor(source, ApeUnit(target))


@given(st.floats(-1e6, 1e6, allow_nan=False))
def test_clock_offset_parses_any_finite_number(seconds: float) -> None:
    assert ClockOffset.parse(repr(seconds)).engine_value() == seconds
    assert ClockOffset.parse(" AUTO ").engine_value() == "auto"


@pytest.mark.parametrize("text", ["nan", "inf", "-inf", "soon", ""])
def test_clock_offset_refuses_what_is_not_seconds(text: str) -> None:
    with pytest.raises(ConfigError, match="--offset"):
        ClockOffset.parse(text)


def test_positional_shapes(tmp_path: Path) -> None:
    assert read_positionals(["tum", "a.txt", "b.txt"]).fmt is InputFormat.TUM
    bag = read_positionals(["bag2", "log", "/a", "/b#c"])
    assert (bag.log_a, bag.gazebo_topic, bag.unity_topic) == (Path("log"), "/a", "/b#c")
    plain = read_positionals(["log.mcap", "/x", "/y"])
    assert (plain.gazebo_topic, plain.unity_topic, plain.log_b) == ("/x", "/y", None)
    assert read_positionals(["a.txt", "b.txt"]).log_b == Path("b.txt")
    for words in ([], ["kitti", "a"], ["bag", "log", "/a"], ["a", "b", "c", "d"]):
        with pytest.raises(ConfigError):
            read_positionals(words)


@given(st.lists(st.sampled_from(["--align", "se3", "-a", "--json", "x"]), max_size=8))
def test_bare_align_becomes_a_only_where_no_value_follows(args: list[str]) -> None:
    out = evo_bare_align(args)
    assert len(out) == len(args)
    for i, (before, after) in enumerate(zip(args, out, strict=True)):
        bare = before == "--align" and (i + 1 == len(args) or args[i + 1].startswith("-"))
        assert after == ("-a" if bare else before)


def test_defaults_follow_the_inputs() -> None:
    files = CompareOptions(CompareInputs(Path("a.txt"), Path("b.txt")))
    assert files.sync_method is SyncMethod.NEAREST
    log = CompareOptions(CompareInputs(Path("run.mcap")))
    assert log.sync_method is SyncMethod.INTERP
    kitti = CompareOptions(CompareInputs(Path("a"), Path("b"), fmt=InputFormat.KITTI))
    assert kitti.sync_method is SyncMethod.NEAREST
    asked = CompareOptions(CompareInputs(Path("a.txt"), Path("b.txt")), sync=SyncMethod.INTERP)
    assert asked.engine_options()["sync"] == "interp"


def test_evo_flags_make_one_alignment() -> None:
    def mode(**given: object) -> AlignmentMode:
        return compare_options({"words": ["a.txt", "b.txt"], **given}).align

    assert mode(evo_align=True) is AlignmentMode.SE3
    assert mode(evo_align=True, correct_scale=True) is AlignmentMode.SIM3
    assert mode(correct_scale=True) is AlignmentMode.SCALE
    assert mode(correct_scale=True, align_origin=True) is AlignmentMode.SCALE_ORIGIN
    assert mode(align="sim3") is AlignmentMode.SIM3
    with pytest.raises(ConfigError, match="contradicts"):
        mode(align="se3", evo_align=True, correct_scale=True)


def test_a_max_diff_alone_means_evos_association() -> None:
    opts = compare_options({"words": ["run.mcap"], "max_diff": 0.02})
    assert opts.sync is SyncMethod.NEAREST and opts.max_diff == 0.02
    assert compare_options({"words": ["run.mcap"]}).sync is None


def test_time_window_checks() -> None:
    with pytest.raises(ConfigError, match="after --t_end"):
        TimeWindow(t_start=2.0, t_end=1.0)
    with pytest.raises(ConfigError, match="--downsample"):
        TimeWindow(downsample=0)
    assert not TimeWindow().active and TimeWindow(downsample=3).active
