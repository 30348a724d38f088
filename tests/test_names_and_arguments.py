"""Name expansion, remapping, --ros-args parsing and ROS 2 parameter files (pure, no DDS)."""

from __future__ import annotations

from pathlib import Path

import pytest

from node_runtime.arguments import ArgumentError, parse_ros_args, split_ros_args
from node_runtime.names import (
    NameError_,
    RemapRule,
    dds_topic_name,
    expand_topic_name,
    remap_topic,
)
from node_runtime.parameters import ParameterError, load_params_file


@pytest.mark.parametrize(("name", "ns", "expected"), [
    ("chatter", "/", "/chatter"),
    ("chatter", "/robot", "/robot/chatter"),
    ("/abs/topic", "/robot", "/abs/topic"),
    ("~/pose", "/robot", "/robot/tracker/pose"),
    ("~", "/", "/tracker"),
])
def test_expansion_follows_ros2_rules(name: str, ns: str, expected: str) -> None:
    assert expand_topic_name(name, "tracker", ns) == expected


def test_invalid_names_are_rejected_with_the_bad_token() -> None:
    with pytest.raises(NameError_, match="9lives"):
        expand_topic_name("9lives", "n", "/")
    with pytest.raises(NameError_, match="empty"):
        expand_topic_name("", "n", "/")


def test_remap_matches_expanded_names_and_respects_node_targets() -> None:
    rules = [RemapRule.parse("other:image:=ignored"), RemapRule.parse("image:=/camera/rgb")]
    assert remap_topic("/robot/image", rules, "tracker", "/robot") == "/camera/rgb"
    assert remap_topic("/robot/depth", rules, "tracker", "/robot") == "/robot/depth"
    assert dds_topic_name("/camera/rgb") == "rt/camera/rgb"


def test_ros_args_section_is_split_and_parsed(tmp_path: Path) -> None:
    params = tmp_path / "p.yaml"
    params.write_text("/**:\n  ros__parameters:\n    a: 1\n")
    argv = ["prog", "--user", "--ros-args", "-r", "__ns:=/x", "-r", "a:=b", "-p", "rate:=2.5",
            "-p", "tags:=[1, 2]", "--params-file", str(params), "--log-level", "debug", "--",
            "--more-user"]
    user, _ros = split_ros_args(argv)
    assert user == ["prog", "--user", "--more-user"]
    args = parse_ros_args(argv)
    assert args.special("__ns", "any") == "/x"
    assert args.params == [(None, "rate", 2.5), (None, "tags", [1, 2])]
    assert args.params_files == [params]
    assert args.log_level == "debug"


def test_bad_ros_args_say_what_is_wrong(tmp_path: Path) -> None:
    with pytest.raises(ArgumentError, match="unknown ROS argument"):
        parse_ros_args(["--ros-args", "--bogus"])
    with pytest.raises(ArgumentError, match="no such file"):
        parse_ros_args(["--ros-args", "--params-file", str(tmp_path / "missing.yaml")])
    with pytest.raises(ArgumentError, match=r":="):
        parse_ros_args(["--ros-args", "-p", "novalue"])


def test_params_file_wildcards_nesting_and_precedence(tmp_path: Path) -> None:
    path = tmp_path / "params.yaml"
    path.write_text(
        "/**:\n  ros__parameters:\n    common: 1\n    who: all\n"
        "/robot/tracker:\n  ros__parameters:\n    who: me\n    nested: {k: 3}\n"
        "robot:\n  other:\n    ros__parameters:\n      who: other\n"
    )
    assert load_params_file(path, "/robot/tracker") == {"common": 1, "who": "me", "nested.k": 3}
    assert load_params_file(path, "/robot/other") == {"common": 1, "who": "other"}
    assert load_params_file(path, "/elsewhere") == {"common": 1, "who": "all"}


def test_malformed_params_file_names_the_file(tmp_path: Path) -> None:
    path = tmp_path / "bad.yaml"
    path.write_text("node: [1, 2\n")
    with pytest.raises(ParameterError, match=r"bad\.yaml"):
        load_params_file(path, "/node")


def test_shipped_parameter_file_matches_the_nodes_parameters() -> None:
    import importlib

    path = Path(__file__).resolve().parents[1] / "config" / "twinslam.yaml"
    for node in ("sequence_player", "device_tracker", "edge_mapper", "udt_node"):
        declared = importlib.import_module(f"{node}.node").PARAMETERS
        given = load_params_file(path, f"/{node}")
        assert set(given) <= set(declared), f"{node}: unknown {set(given) - set(declared)}"
        for key, value in given.items():
            assert isinstance(value, type(declared[key])), f"{node}.{key} has the wrong type"
