"""Which sections of a parameter file reach a node, by rcl's rules, and the warning a node
gives at start when a file names it under a key that cannot reach it (a plain node name read by
a node in a namespace): the rules checked against rclpy's own parameter overrides."""

from __future__ import annotations

from pathlib import Path

import pytest

from twinslam.hosts.loopback import LoopbackDomain
from twinslam.node_runtime.parameter_files import key_reaches, params_files, unreached_sections

#: (key, node's fully qualified name, whether rcl gives that node the section)
CASES = [("device_tracker", "/device_tracker", True),
         ("device_tracker", "/ar1/device_tracker", False),
         ("/device_tracker", "/ar1/device_tracker", False),
         ("/**/device_tracker", "/device_tracker", True),
         ("/**/device_tracker", "/ar1/device_tracker", True),
         ("/**/device_tracker", "/site/ar1/device_tracker", True),
         ("/*/device_tracker", "/ar1/device_tracker", True),
         ("/*/device_tracker", "/site/ar1/device_tracker", False),
         ("/ar1/device_tracker", "/ar1/device_tracker", True),
         ("/ar1/device_tracker", "/ar2/device_tracker", False),
         ("/**/edge_mapper", "/ar1/device_tracker", False),
         ("/**", "/ar1/device_tracker", True)]


@pytest.mark.parametrize(("key", "fqn", "reaches"), CASES)
def test_a_key_reaches_the_nodes_rcl_gives_it_to(key: str, fqn: str, reaches: bool) -> None:
    assert key_reaches(key, fqn) is reaches


def test_the_rules_are_rclpys(tmp_path: Path, domain: LoopbackDomain) -> None:
    """Each case read by a real node: the section's value arrives exactly where the rule says."""
    import rclpy
    from rclpy.node import Node

    for i, (key, fqn, reaches) in enumerate(CASES):
        params = tmp_path / f"p{i}.yaml"
        params.write_text(f"{key}:\n  ros__parameters:\n    probe: {i}\n", encoding="utf-8")
        namespace, name = fqn.rsplit("/", 1)
        context = rclpy.Context()
        rclpy.init(args=["node", "--ros-args", "--params-file", str(params)], context=context,
                   domain_id=domain.domain_id)
        try:
            node = Node(name, namespace=namespace or "/", context=context,
                        automatically_declare_parameters_from_overrides=True)
            got = node.get_parameter_or("probe", None).value
            node.destroy_node()
        finally:
            rclpy.shutdown(context=context)
        assert (got == i) is reaches, (key, fqn, got)


def test_params_files_are_read_from_the_ros_arguments_only() -> None:
    argv = ["node", "--params-file", "not-ros.yaml", "--ros-args", "-r", "__ns:=/ar1",
            "--params-file", "a.yaml", "-p", "x:=1", "--", "--params-file", "after.yaml",
            "--ros-args", "--params-file", "b.yaml"]
    assert params_files(argv) == [Path("a.yaml"), Path("b.yaml")]


def test_a_file_keyed_by_plain_names_is_named_to_a_node_in_a_namespace(tmp_path: Path) -> None:
    plain = tmp_path / "plain.yaml"
    plain.write_text("device_tracker:\n  ros__parameters:\n    slot_frames: 60\n"
                     "/**:\n  ros__parameters:\n    use_sim_time: false\n", encoding="utf-8")
    wild = tmp_path / "wild.yaml"
    wild.write_text("/**/device_tracker:\n  ros__parameters:\n    slot_frames: 60\n",
                    encoding="utf-8")
    assert unreached_sections([plain], "device_tracker", "/ar1") == [
        f"'device_tracker' in {plain}"]
    assert unreached_sections([plain], "device_tracker", "/") == []
    assert unreached_sections([wild], "device_tracker", "/ar1") == []
    # each file on its own: ros2 launch adds one that reaches the node (the launch file's
    # own parameters), and the user's file still gives it nothing
    launch_own = tmp_path / "launch_params.yaml"
    launch_own.write_text("/ar1/device_tracker:\n  ros__parameters:\n    map_frame: ar1/map\n",
                          encoding="utf-8")
    assert unreached_sections([plain, launch_own], "device_tracker", "/ar1") == [
        f"'device_tracker' in {plain}"]
    assert unreached_sections([plain, wild], "device_tracker", "/ar1") == [
        f"'device_tracker' in {plain}"]
    assert unreached_sections([plain], "edge_mapper", "/ar1") == []
    assert unreached_sections([tmp_path / "missing.yaml"], "device_tracker", "/ar1") == []


def test_a_node_in_a_namespace_warns_of_a_section_that_cannot_reach_it(
        tmp_path: Path, domain: LoopbackDomain, monkeypatch: pytest.MonkeyPatch) -> None:
    """The fleet's devices ran on their defaults with a file keyed ``device_tracker:``; a
    node started so now says which section, and how to key it."""
    import rclpy
    from rclpy.node import Node

    from device_tracker.parameters import PARAMETERS
    from twinslam.node_runtime.parameters import declare

    plain = tmp_path / "plain.yaml"
    plain.write_text("device_tracker:\n  ros__parameters:\n    slot_frames: 60\n",
                     encoding="utf-8")
    argv = ["device_tracker", "--ros-args", "-r", "__ns:=/ar1", "--params-file", str(plain)]
    warned: list[str] = []

    class Logger:
        def warning(self, text: str) -> None:
            warned.append(text)

    context = rclpy.Context()
    rclpy.init(args=argv, context=context, domain_id=domain.domain_id)
    try:
        node = Node("device_tracker", context=context)
        monkeypatch.setattr(node, "get_logger", Logger)
        values = declare(node, PARAMETERS, argv)
        node.destroy_node()
    finally:
        rclpy.shutdown(context=context)
    assert values["slot_frames"] == next(s.default for s in PARAMETERS
                                         if s.name == "slot_frames")
    assert len(warned) == 1 and f"'device_tracker' in {plain}" in warned[0]
    assert "does not reach /ar1/device_tracker" in warned[0]
    assert "key it /**/device_tracker (any namespace) or /ar1/device_tracker" in warned[0]
