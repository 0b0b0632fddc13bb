"""Issue 16: the default thresholds are keyed by role (vehicle / camera), never by topic name.

The same good log passes whatever its topics are called; ROS_example.bag (evo's test data)
fails only on its values, never with a "no-match" for a name.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest
from seeded_motion import moving_vehicle
from shared_data import shared

from uwval.comparison import compare_logs
from uwval.errors import ConfigError
from uwval.gate import check, parse_thresholds
from uwval.gate.rules import topic_role
from uwval.io.writers import open_writer, write_stream
from uwval.resources import data_path
from uwval.results import ResultsTable

_pose = moving_vehicle


def _log(path: Path, ref_topic: str, oth_topic: str) -> Path:
    with open_writer(path) as w:
        write_stream(w, ref_topic, _pose(1), "enu")
        write_stream(w, oth_topic, _pose(2), "enu")
    return path


def _gate(log: Path, **topics: str):  # type: ignore[no-untyped-def]
    lc = compare_logs(log, **topics)
    table = ResultsTable.from_comparisons([("run", {}, lc.to_json())])
    return check(table, data_path("thresholds", "default.toml"))


def test_the_same_good_log_passes_under_any_topic_names(tmp_path: Path) -> None:
    default = _gate(_log(tmp_path / "a.mcap", "/gazebo/model_rov_pose", "/unity/model_rov_pose"))
    renamed = _gate(
        _log(tmp_path / "b.mcap", "/model/tethys/pose", "/unity/tethys/pose"),
        gazebo_topic="/model/tethys/pose",
        unity_topic="/unity/tethys/pose",
    )
    assert default.passed, default.format()
    assert renamed.passed, renamed.format()
    assert renamed.checked == default.checked == 15  # 4 x 3 axes + Pearson r on x, y, yaw


def test_a_bad_renamed_log_still_fails_on_its_values(tmp_path: Path) -> None:
    log = tmp_path / "bad.mcap"
    with open_writer(log) as w:
        write_stream(w, "/a/pose", _pose(1), "enu")
        off = _pose(2)
        write_stream(w, "/b/pose", off.with_(position=off.position + 0.5), "enu")
    res = _gate(log, gazebo_topic="/a/pose", unity_topic="/b/pose")
    assert not res.passed
    kinds = {v.kind.value for v in res.violations}
    assert kinds == {"threshold"}


def test_ros_example_bag_does_not_fail_for_names(tmp_path: Path) -> None:
    src = shared("bags", "evo", "ROS_example.bag")
    bag = tmp_path / "ROS_example.bag"
    shutil.copyfile(src, bag)
    res = _gate(bag, gazebo_topic="groundtruth", unity_topic="ORB-SLAM")
    assert res.checked == 15
    assert all(v.kind.value != "no-match" for v in res.violations)  # values only (metres off)


def test_role_rules_parse_and_skip_when_no_topic_has_the_role(tmp_path: Path) -> None:
    th = parse_thresholds(
        {"threshold": [{"metric": "mae", "axes": ["x"], "roles": ["camera"], "max": 0.01}]}
    )
    assert th.rules[0].roles == ("camera",)
    assert parse_thresholds({"threshold": [{"metric": "mae", "role": "any", "max": 1}]}).rules[
        0
    ].roles == ("vehicle", "camera")
    with pytest.raises(ConfigError, match="unknown role"):
        parse_thresholds({"threshold": [{"metric": "mae", "roles": ["boat"], "max": 1}]})
    lc = compare_logs(_log(tmp_path / "c.mcap", "/x/pose", "/y/pose"), gazebo_topic="/x/pose",
                      unity_topic="/y/pose")  # fmt: skip
    table = ResultsTable.from_comparisons([("run", {}, lc.to_json())])
    res = check(table, th)
    assert res.checked == 0
    assert any("no camera topic" in s for s in res.skipped)
    assert not res.passed  # every rule skipped: nothing was checked, so no PASS
    # a name-keyed rule that matches nothing still fails (a typo must not pass silently)
    typo = parse_thresholds({"threshold": [{"metric": "mae", "topics": ["nope"], "max": 1}]})
    assert not check(table, typo).passed


@pytest.mark.parametrize(
    ("topic", "role"),
    [
        ("model_rov_pose", "vehicle"),
        ("gui_camera_pose", "camera"),
        ("tethys/pose", "vehicle"),
        ("groundtruth~ORB-SLAM", "vehicle"),
        ("camera/pose", "camera"),
    ],
)
def test_topic_role(topic: str, role: str) -> None:
    assert topic_role(topic) == role


def test_a_role_rule_with_a_misspelt_metric_fails(tmp_path: Path) -> None:
    """A rule keyed by role is skipped only when no topic has that role: a vehicle topic
    whose values the rule cannot find (a misspelt metric) is a failure, not a pass."""
    log = _log(tmp_path / "a.mcap", "/gazebo/model_rov_pose", "/unity/model_rov_pose")
    lc = compare_logs(log)
    table = ResultsTable.from_comparisons([("run", {}, lc.to_json())])
    rules = tmp_path / "t.toml"
    rules.write_text('[[threshold]]\nmetric = "rmse_typo"\nrole = "vehicle"\nmax = 0.001\n')
    result = check(table, rules)
    assert not result.passed, result.format()
    assert result.checked == 0
    camera_only = tmp_path / "c.toml"
    camera_only.write_text('[[threshold]]\nmetric = "mae"\nrole = "camera"\nmax = 0.001\n')
    skipped = check(table, camera_only)  # no camera topic in this log: skipped, with why,
    assert skipped.skipped, skipped.format()
    assert not skipped.passed  # and a gate that checked nothing at all does not pass
    assert "every rule was skipped" in skipped.format()
