"""Held-key teleop factors of experiment files (issue 18): the level is each held key's
force (N) or torque (N m); errors name the file, the factor and what is wrong."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from uwval.errors import ConfigError
from uwval.simulator import load_experiment


def _exp(tmp_path: Path, factor: str) -> Path:
    p = tmp_path / "keys.toml"
    p.write_text('name = "k"\nduration_s = 2.0\n' + factor)
    return p


def test_key_factor_levels_scale_the_held_keys(tmp_path: Path) -> None:
    p = _exp(tmp_path, '[factors.force]\nkeys = "i@0:1; b@0.5:1.5"\nlevels = [2.0, 8.0]\n')
    runs = load_experiment(p).runs()
    for r in runs:
        f, tq, _ = r.inputs.evaluate(np.array([0.25, 0.75, 1.25, 1.75]))
        lv = r.factors["force"]
        np.testing.assert_array_equal(f[:, 0], [lv, lv, 0, 0])  # surge while i is held
        np.testing.assert_array_equal(f[:, 2], [0, -lv, -lv, 0])  # heave down while b is held
        assert not tq.any()


@pytest.mark.parametrize(
    ("factor", "needle"),
    [
        ('[factors.force]\nkeys = "j@0:1"\nlevels = [1.0]\n', "force keys only; j drive"),
        ('[factors.torque]\nkeys = "i@0:1"\nlevels = [1.0]\n', "torque keys only; i drive"),
        ('[factors.current]\nkeys = "i@0:1"\nlevels = [1.0]\n', "not current"),
        ('[factors.force]\nkeys = "i@0:1"\naxis = "y"\nlevels = [1.0]\n', "not both"),
        ('[factors.force]\nkeys = "q@0:1"\nlevels = [1.0]\n', "unknown teleop key 'q'"),
        ('[factors.force]\nkeys = "i0:1"\nlevels = [1.0]\n', "KEY@START:END"),
        ("[factors.force]\nkeys = 3\nlevels = [1.0]\n", "key script"),
    ],
)
def test_bad_key_factors_are_named(tmp_path: Path, factor: str, needle: str) -> None:
    with pytest.raises(ConfigError, match=r"keys\.toml: factor table factors") as e:
        load_experiment(_exp(tmp_path, factor))
    assert needle in str(e.value)
