"""uwval.io.bagmeta: the fast reader of rosbag2 metadata.yaml answers exactly as ruamel.yaml's
safe load wherever it answers, answers on every real bag's metadata we have, and declines
(ruamel then reads) whatever is outside its subset."""

from __future__ import annotations

import io
from pathlib import Path
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from ruamel.yaml import YAML

from uwval.io.bagmeta import load_metadata, parse_block_yaml
from uwval.io.raw import load_yaml

SHARED = Path(__file__).resolve().parents[3] / "shared" / "data"


def _shared_metadata() -> list[Path]:
    return sorted(SHARED.rglob("metadata.yaml"))


@pytest.mark.parametrize("path", _shared_metadata(), ids=lambda p: p.parent.name)
def test_every_shared_bags_metadata_is_read_by_the_fast_reader_as_ruamel_reads_it(
    path: Path,
) -> None:
    text = path.read_text()
    got = parse_block_yaml(text)
    assert got is not None, "real rosbag2 metadata must take the fast path"
    assert got == load_yaml(text)


def test_the_shared_data_has_metadata_files() -> None:
    assert len(_shared_metadata()) >= 9  # yaml-cpp (Humble, Jazzy) and rosbags writers


@pytest.mark.parametrize("fmt", ["rosbag2", "rosbag2-mcap"])
def test_metadata_our_writers_produce_takes_the_fast_path(tmp_path: Path, fmt: str) -> None:
    from uwval.comparison.synthetic import vehicle_motion
    from uwval.io.writers import open_writer, write_stream

    out = tmp_path / "bag"
    with open_writer(out, fmt) as w:
        write_stream(w, "/gazebo/model_rov_pose", vehicle_motion(50), "enu")
    text = (out / "metadata.yaml").read_text()
    got = parse_block_yaml(text)
    assert got is not None and got == load_yaml(text)


_YAML_CPP = """\
rosbag2_bagfile_information:
  version: 5
  storage_identifier: sqlite3
  duration:
    nanoseconds: 7
  relative_file_paths:
    - rosbag2_2024_01_01-12_00_00_0.db3
  topics_with_message_count:
    - topic_metadata:
        name: /tf
        type: tf2_msgs/msg/TFMessage
        serialization_format: cdr
        offered_qos_profiles: "- history: 3\\n  depth: 0\\n  durability:\\
          \\ 2\\n  avoid_ros_namespace_conventions: false"
        type_description_hash: RIHS01_abc
      message_count: 3
  compression_format: ""
  compression_mode: ""
  files:
    - path: a.db3
      starting_time:
        nanoseconds_since_epoch: -5
  custom_data: ~
  ros_distro: jazzy
"""


def test_yaml_cpp_layout_indented_sequences_and_folded_escapes() -> None:
    got = parse_block_yaml(_YAML_CPP)
    assert got is not None
    assert got == load_yaml(_YAML_CPP)
    qos = got["rosbag2_bagfile_information"]["topics_with_message_count"][0]["topic_metadata"]
    assert qos["offered_qos_profiles"].startswith("- history: 3\n  depth: 0\n  durability: 2")


@pytest.mark.parametrize(
    "text",
    [
        "a: 1 # a comment\n",
        "# comment\na: 1\n",
        "a: &x 1\nb: *x\n",
        "a: !!str 1\n",
        "a: |\n  text\n",
        "a: >\n  text\n",
        "a: [1, 2]\n",
        "a: {b: 1}\n",
        "a:\n\t- 1\n",
        "---\na: 1\n",
        "%YAML 1.1\n---\na: 1\n",
        "a: yes\n",
        "a: off\n",
        "a: 1.5\n",
        "a: 2024-01-01\n",
        "a: 0x1F\n",
        "a: 007\n",
        "a: .inf\n",
        "a: 1\na: 2\n",
        "'a': 1\n",
        "? a\n: 1\n",
        "true: 1\n",
        "a: 'multi\n  line'\n",
        'a: "bad \\q escape"\n',
        'a: "unclosed\n',
        "a: b: c\n",
        "- 1\n- 2\n",
        "plain\n",
        "",
        "a:\n  - - 1\n",
        'a: "x" y\n',
    ],
)
def test_anything_outside_the_subset_is_declined_and_ruamel_decides(text: str) -> None:
    assert parse_block_yaml(text) is None
    try:
        want: Any = load_yaml(text)
    except Exception as exc:  # invalid YAML: load_metadata raises ruamel's error too
        with pytest.raises(type(exc)):
            load_metadata(text)
        return
    assert load_metadata(text) == want


_words = st.text(alphabet=st.sampled_from("abcxyz_/ABZ09-.:# '\"\\\n\té~"), min_size=0, max_size=30)
_scalars = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(-(2**63), 2**63),
    _words,
    st.sampled_from(
        ["/tf", "geometry_msgs/msg/PoseStamped", "cdr", "sqlite3", "", "RIHS01_0f", "yes"]
    ),
)
_keys = st.text(alphabet=st.sampled_from("abcdefgh_xyz"), min_size=1, max_size=12)
_docs = st.recursive(
    _scalars,
    lambda inner: st.one_of(st.lists(inner, max_size=4), st.dictionaries(_keys, inner, max_size=5)),
    max_leaves=25,
)


def _dump(doc: Any, width: int, indent: tuple[int, int]) -> str:
    y = YAML(typ="safe", pure=True)
    y.default_flow_style = False
    y.width = width
    y.indent(mapping=indent[0], sequence=indent[0] + indent[1], offset=indent[1])
    buf = io.StringIO()
    y.dump(doc, buf)
    return buf.getvalue()


@settings(max_examples=300, deadline=None)
@given(
    doc=st.dictionaries(_keys, _docs, min_size=1, max_size=6),
    width=st.sampled_from([20, 40, 80, 4096]),
    indent=st.sampled_from([(2, 0), (2, 2), (4, 2)]),
)
def test_any_dumped_document_is_read_as_ruamel_reads_it_or_declined(
    doc: dict[str, Any], width: int, indent: tuple[int, int]
) -> None:
    text = _dump(doc, width, indent)
    got = parse_block_yaml(text)
    want = load_yaml(text)
    assert got is None or got == want
    assert load_metadata(text) == want


_rosbag2_like = st.fixed_dictionaries(
    {
        "version": st.integers(1, 9),
        "storage_identifier": st.sampled_from(["sqlite3", "mcap"]),
        "relative_file_paths": st.lists(
            st.from_regex(r"[a-z][a-z0-9_]{0,20}\.(db3|mcap)", fullmatch=True), max_size=3
        ),
        "duration": st.fixed_dictionaries({"nanoseconds": st.integers(0, 2**62)}),
        "topics_with_message_count": st.lists(
            st.fixed_dictionaries(
                {
                    "message_count": st.integers(0, 10**9),
                    "topic_metadata": st.fixed_dictionaries(
                        {
                            "name": st.from_regex(
                                r"/[a-z_]{1,10}(/[a-z_]{1,10}){0,3}", fullmatch=True
                            ),
                            "type": st.sampled_from(
                                ["geometry_msgs/msg/PoseStamped", "tf2_msgs/msg/TFMessage"]
                            ),
                            "serialization_format": st.just("cdr"),
                            "offered_qos_profiles": st.one_of(
                                st.just(""),
                                st.just("- history: 3\n  depth: 0\n  reliability: 1"),
                                st.lists(
                                    st.dictionaries(
                                        st.sampled_from(["history", "depth", "reliability"]),
                                        st.integers(0, 9),
                                    ),
                                    max_size=2,
                                ),
                            ),
                        }
                    ),
                }
            ),
            max_size=4,
        ),
        "compression_format": st.sampled_from(["", "zstd"]),
        "compression_mode": st.sampled_from(["", "FILE", "MESSAGE"]),
        "custom_data": st.none(),
    }
)


@settings(max_examples=150, deadline=None)
@given(info=_rosbag2_like, width=st.sampled_from([40, 80, 4096]))
def test_rosbag2_shaped_documents_always_take_the_fast_path(
    info: dict[str, Any], width: int
) -> None:
    text = _dump({"rosbag2_bagfile_information": info}, width, (2, 0))
    got = parse_block_yaml(text)
    assert got is not None and got == load_yaml(text)
