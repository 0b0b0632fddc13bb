"""GazeboModel: its JSON form round-trips, the experiment file's keys (new and old spellings)
give the model they name, and a bad value is refused in one line naming the key."""

from __future__ import annotations

from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st

from uwval.errors import ConfigError
from uwval.simulator import (
    AddedMass,
    CaSign,
    CoriolisEntries,
    GazeboModel,
    load_experiment,
)
from uwval.simulator.dynamics import build_params
from uwval.simulator.presets import load_vehicle

MODELS = st.builds(
    GazeboModel,
    coriolis=st.sampled_from(CoriolisEntries),
    added_mass=st.sampled_from(AddedMass),
    ca_sign=st.sampled_from(CaSign),
    zero_prev_state=st.booleans(),
    int_abs_damping=st.booleans(),
)


@given(MODELS)
def test_json_form_round_trips_and_reaches_the_kernel(model: GazeboModel) -> None:
    assert GazeboModel(**model.to_dict()) == model
    s = build_params([load_vehicle("tethys")], 1e-3, model, has_current=True, wrench_frame="body")
    st_ = s.structure
    assert (st_.implicit, st_.legacy, st_.fossen, st_.int_abs) == (
        model.implicit,
        model.legacy_coriolis,
        model.fossen,
        model.int_abs_damping,
    )


def _exp(tmp_path: Path, keys: str) -> GazeboModel:
    p = tmp_path / "e.toml"
    p.write_text(keys + "\nduration_s = 1.0\n[factors.force]\nlevels = [1.0]\n")
    return load_experiment(p).model


def test_experiment_keys_name_the_model(tmp_path: Path) -> None:
    assert _exp(tmp_path, "") == GazeboModel()
    new = _exp(tmp_path, 'added_mass = "implicit"\nca_sign = "fossen"\ncoriolis = "legacy"')
    assert new == GazeboModel(CoriolisEntries.LEGACY, AddedMass.IMPLICIT, CaSign.FOSSEN)
    old = _exp(tmp_path, "implicit_added_mass = true\nlegacy_coriolis = true")
    assert old == GazeboModel(CoriolisEntries.LEGACY, AddedMass.IMPLICIT)
    gz8 = _exp(tmp_path, "legacy_gz8 = true")
    assert gz8.legacy_gz8 and not gz8.int_abs_damping
    assert _exp(tmp_path, "int_abs_damping = true").int_abs_damping


def test_a_bad_value_is_refused_naming_the_key(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=r"'ca_sign' must be one of \"gazebo\", \"fossen\""):
        _exp(tmp_path, 'ca_sign = "plus"')
    with pytest.raises(ConfigError, match="'int_abs_damping' must be true or false"):
        _exp(tmp_path, 'int_abs_damping = "yes"')
