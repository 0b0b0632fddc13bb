"""Issue 16, real topic shapes (from the user's side, on third-party logs under ../shared/data):
``/tf#child`` topics, TF pairs in ``inspect``, a warning for different frame_ids, pose-typed
candidates in the "no pose pair" error, an empty bag called empty, labels that do not collide.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from cli_runner import run_uwval
from shared_data import shared

from uwval.comparison.logs import pair_label
from uwval.io.writers import open_writer, write_stream
from uwval.posestream import PoseStream

_shared = shared


@pytest.fixture
def nav2(tmp_path: Path) -> Path:
    dst = tmp_path / "nav2_turtlebot.mcap"
    shutil.copyfile(_shared("evo", "nav2_turtlebot.mcap"), dst)
    return dst


def test_different_frame_ids_are_warned_about(nav2: Path) -> None:
    p = run_uwval("compare", nav2, "--gazebo-topic", "/odom", "--unity-topic", "/amcl_pose")
    assert p.returncode == 0, p.stderr
    assert "warning: the streams are in different frames" in p.stdout
    assert "has frame_id 'odom'" in p.stdout and "has 'map'" in p.stdout
    # the same frame: no such warning (/tf#base_link is odom->base_link, /odom's own pose)
    q = run_uwval("compare", nav2, "--gazebo-topic", "/odom", "--unity-topic", "/tf#base_link")
    assert q.returncode == 0, q.stderr
    assert "different frames" not in q.stdout


def test_a_topic_name_carries_the_tf_child(nav2: Path) -> None:
    p = run_uwval(
        "compare", nav2, "--gazebo-topic", "/odom", "--unity-topic", "/tf#base_link", "--json"
    )
    assert p.returncode == 0, p.stderr
    doc = json.loads(p.stdout)
    assert doc["primary_topic"] == "odom~tf/base_link"
    assert doc["other"]["topic"] == "/tf#base_link"
    assert doc["n_samples"] == 2639
    assert doc["position_error_norm"]["max"] < 1e-12  # odom is published on both
    bad = run_uwval("compare", nav2, "--gazebo-topic", "/odom", "--unity-topic", "/tf")
    assert bad.returncode == 2
    assert "choose the child frame as /tf#CHILD" in bad.stderr
    assert "odom->base_link" in bad.stderr and "Traceback" not in bad.stderr
    missing = run_uwval("compare", nav2, "--gazebo-topic", "/odom", "--unity-topic", "/tf#nope")
    assert missing.returncode == 2
    assert "has no transform *->nope" in missing.stderr


def test_inspect_lists_tf_parent_child_pairs(tmp_path: Path) -> None:
    bag = tmp_path / "tf_example.bag"
    shutil.copyfile(_shared("bags", "evo", "tf_example.bag"), bag)
    p = run_uwval("inspect", bag)
    assert p.returncode == 0, p.stderr
    assert "/tf parent->child: odom->base_footprint (517)" in p.stdout
    assert "/tf_static parent->child: base_footprint->base_link (1)" in p.stdout
    doc = json.loads(run_uwval("inspect", bag, "--json").stdout)
    assert doc["tf_pairs"]["/tf"] == [{"parent": "odom", "child": "base_footprint", "count": 517}]


def test_no_pair_error_lists_pose_topics_only(nav2: Path, tmp_path: Path) -> None:
    p = run_uwval("compare", nav2)
    assert p.returncode == 2
    err = p.stderr.strip()
    assert "pose topics: /amcl_pose (PoseWithCovarianceStamped, 135), /odom (Odometry, 2639)" in err
    assert "TF topics (name a child frame: TOPIC#CHILD" in err and "/tf" in err
    bag = tmp_path / "ROS_example.bag"
    shutil.copyfile(_shared("bags", "evo", "ROS_example.bag"), bag)
    q = run_uwval("compare", bag)
    assert q.returncode == 2
    assert "pose topics: /ORB-SLAM (PoseStamped, 8362), /S-PTAM" in q.stderr
    assert "TF topics" not in q.stderr


def test_empty_bag_says_it_is_empty(tmp_path: Path) -> None:
    bag = tmp_path / "empty_bag"
    shutil.copytree(_shared("bags", "rosbag2", "empty_bag"), bag)
    p = run_uwval("compare", bag)
    assert p.returncode == 2
    assert "the log is empty (2 topic(s), no messages)" in p.stderr
    assert "/rosout" not in p.stderr and "topics: ;" not in p.stderr


def _helix(n: int = 200, seed: int = 0) -> PoseStream:
    rng = np.random.default_rng(seed)
    t = np.arange(n, dtype=np.int64) * 20_000_000 + 1_000_000_000
    s = np.arange(n) * 0.02
    pos = np.stack([np.cos(s), np.sin(s), 0.1 * s], axis=1) + rng.normal(0, 1e-3, (n, 3))
    quat = np.tile([0.0, 0.0, 0.0, 1.0], (n, 1))
    return PoseStream.from_arrays(t, pos, quat, frame="enu")


def test_labels_of_renamed_topics_do_not_collide(tmp_path: Path) -> None:
    log = tmp_path / "renamed.mcap"
    with open_writer(log) as w:
        write_stream(w, "/model/tethys/pose", _helix(seed=1), "enu")
        write_stream(w, "/unity/tethys/pose", _helix(seed=2), "enu")
    p = run_uwval(
        "compare",
        log,
        "--gazebo-topic",
        "/model/tethys/pose",
        "--unity-topic",
        "/unity/tethys/pose",
        "--json",
    )
    assert p.returncode == 0, p.stderr
    assert json.loads(p.stdout)["primary_topic"] == "tethys/pose"


@pytest.mark.parametrize(
    ("g", "u", "label"),
    [
        ("/gazebo/model_rov_pose", "/unity/model_rov_pose", "model_rov_pose"),
        ("/model/tethys/pose", "/unity/tethys/pose", "tethys/pose"),
        ("/odom", "/amcl_pose", "odom~amcl_pose"),
        ("/a/pose", "/a/pose", "a/pose"),
        ("/tf#base_link", "/odom", "tf/base_link~odom"),
    ],
)
def test_pair_label(g: str, u: str, label: str) -> None:
    assert pair_label(g, u) == label


def test_frame_ids_that_name_a_convention_do_not_warn() -> None:
    from uwval.comparison.engine import frame_id_mismatch

    s = _helix()
    assert frame_id_mismatch(s.with_(frame_ids=("world",)), s.with_(frame_ids=("unity-flu",))) == ""
    assert frame_id_mismatch(s.with_(frame_ids=("ENU",)), s.with_(frame_ids=("map",))) == ""
    assert frame_id_mismatch(s.with_(frame_ids=("odom",)), s.with_(frame_ids=("odom",))) == ""
    assert "different frames" in frame_id_mismatch(
        s.with_(frame_ids=("odom",)), s.with_(frame_ids=("map",))
    )


def test_two_logs_without_topics_list_pose_topics_only(nav2: Path, tmp_path: Path) -> None:
    bag = tmp_path / "talker_mcap"
    shutil.copytree(_shared("bags", "rosbag2", "talker_mcap"), bag)
    p = run_uwval("compare", bag, nav2)
    assert p.returncode == 2
    assert "talker_mcap: name the topic to compare" in p.stderr
    assert "pose topics: none (3 other topic(s))" in p.stderr and "/rosout" not in p.stderr
    q = run_uwval("compare", nav2, nav2, "--unity-topic", "/odom")
    assert q.returncode == 2
    assert "pose topics: /amcl_pose, /odom, /tf#CHILD" in q.stderr
