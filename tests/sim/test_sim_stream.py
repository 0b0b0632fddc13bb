"""SimulationStream: the run handed out chunk by chunk, equal to simulate() bit for bit."""

from __future__ import annotations

import numpy as np
import pytest

from uwval.simulator import (
    SimulationStream,
    constant_inputs,
    load_vehicle,
    simulate,
)
from uwval.simulator.errors import SimulationError

FIELDS = (
    ("t", "vehicle", "t"),
    ("position", "vehicle", "position"),
    ("orientation", "vehicle", "orientation"),
    ("camera_position", "camera", "position"),
    ("camera_orientation", "camera", "orientation"),
)


def _joined(chunks: list, name: str) -> np.ndarray:
    return np.concatenate([getattr(c, name) for c in chunks])


@pytest.mark.parametrize("chunk_ticks", [1, 7, 1000])
@pytest.mark.parametrize("background", [False, True])
def test_streamed_run_equals_simulate(chunk_ticks: int, background: bool) -> None:
    vehicle = load_vehicle("tethys")
    inputs = constant_inputs((10, 0, 0), (0, 0, 1), (0, 0.2, 0))
    whole = simulate(vehicle, inputs, 7.37, publish_rate=50)
    stream = SimulationStream(
        vehicle, inputs, 7.37, publish_rate=50, chunk_ticks=chunk_ticks, background=background
    )
    assert stream.background is background
    chunks = list(stream)
    assert max(len(c) for c in chunks) <= chunk_ticks
    for name, side, attr in FIELDS:
        assert np.array_equal(_joined(chunks, name), getattr(getattr(whole, side), attr)), name
    assert np.array_equal(_joined(chunks, "velocity"), whole.velocity)
    assert stream.info["steps"] == whole.info["steps"]
    assert stream.info["vehicle"] == whole.info["vehicle"] == "tethys"


def test_a_diverging_streamed_run_raises_like_simulate() -> None:
    vehicle = load_vehicle("bluerov2_heavy")
    inputs = constant_inputs((0, 0, 0), (0, 0, 0), (0, 0, 0))
    with pytest.raises(SimulationError, match="diverged") as whole:
        simulate(vehicle, inputs, 5.0)
    for background in (False, True):
        with pytest.raises(SimulationError, match="diverged") as streamed:
            list(SimulationStream(vehicle, inputs, 5.0, background=background))
        assert str(streamed.value) == str(whole.value)


def test_a_stream_is_iterated_once() -> None:
    stream = SimulationStream(load_vehicle("tethys"), None, 0.1)
    list(stream)
    with pytest.raises(SimulationError, match="once"):
        list(stream)
