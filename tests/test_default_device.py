"""One default device for the product: what a user gets from the nodes' own defaults, from
``twinslam launch`` and ``evaluate`` (the bundled parameter file) and from the launch file is the
same device — the one the default-device sweep measured best — and the paper's Table I device is
one named parameter file that keeps Table I exactly."""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from typing import Any

import pytest
import yaml

from twinslam.cli.commands.launch import policies_of
from twinslam.cli.commands.parameters import NODES as REFERENCE_NODES
from twinslam.cli.main import build_parser
from twinslam.live.launcher import DEFAULT_PARAMS, PAPER_PARAMS
from twinslam.node_runtime.parameters import ParamSpec
from twinslam.slam.front_end.map_source import DEFAULT_MAP_SOURCE, EDGE, EDGE_LOCAL
from twinslam.slot_protocol import default_device, table1

NODES: dict[str, Sequence[ParamSpec]] = {name: specs for name, _, specs in REFERENCE_NODES}
#: set in the bundled file on purpose, not the node's default: a player started by hand plays
#: at once; one the launch starts waits for the device
LAUNCH_CHOICES = {("sequence_player", "wait_for_subscribers")}


def _command(name: str) -> argparse.ArgumentParser:
    (sub,) = [a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction)]
    return sub.choices[name]


def _file(path: Any) -> dict[str, dict[str, Any]]:
    """Node name → its values (a section keyed ``/**/NODE`` is node NODE's)."""
    return {node.removeprefix("/**/"): body["ros__parameters"] for node, body in
            yaml.safe_load(path.read_text(encoding="utf-8")).items()}


def _default(node: str, name: str) -> Any:
    return next(p.default for p in NODES[node] if p.name == name)


def test_the_bundled_parameter_file_sets_nothing_the_nodes_would_not_start_with() -> None:
    """A node started without the file is the same device as one started with it."""
    for node, values in _file(DEFAULT_PARAMS).items():
        for name, value in values.items():
            if (node, name) in LAUNCH_CHOICES:
                continue
            default = _default(node, name)
            assert value == default or (
                isinstance(value, float | int) and float(value) == float(default)), (
                f"{node}.{name}: the file says {value!r}, the node starts with {default!r}")


def test_the_default_device_is_the_measured_one_everywhere() -> None:
    assert (DEFAULT_MAP_SOURCE, _default("device_tracker", "map_source")) == (EDGE_LOCAL,) * 2
    assert _default("device_tracker", "slot_frames") == default_device.SLOT_FRAMES == 30
    assert _default("edge_mapper", "policy") == default_device.POLICY == "lff"
    assert _default("edge_mapper", "d_req_s") == default_device.D_REQ_S
    assert _default("sequence_player", "colour_intrinsics") == "auto"
    evaluate = next(a for a in _command("evaluate")._actions if "--map-source" in a.option_strings)
    assert evaluate.default == EDGE_LOCAL
    assert policies_of(_command("launch").parse_args([])) == ["lff"]


def test_launch_runs_the_parameter_files_policy_unless_told_another() -> None:
    """``twinslam launch --params config/paper-table1.yaml`` is the paper's Table I device,
    ADAPT included, as ``ros2 launch … params_file:=…`` is; ``--policy`` still chooses."""
    launch = _command("launch")
    assert policies_of(launch.parse_args(["--params", str(PAPER_PARAMS)])) == ["adapt"]
    assert policies_of(launch.parse_args(["--params", str(PAPER_PARAMS),
                                          "--policy", "lff,pu"])) == ["lff", "pu"]
    assert policies_of(launch.parse_args(["--params", str(DEFAULT_PARAMS)])) == ["lff"]


def test_the_papers_preset_keeps_table_i_exactly() -> None:
    paper = _file(PAPER_PARAMS)
    device, edge = paper["device_tracker"], paper["edge_mapper"]
    assert (device["slot_frames"], edge["d_req_s"]) == (table1.SLOT_FRAMES, table1.D_REQ_S)
    assert (device["map_source"], edge["policy"], device["own_map_after_s"]) == (
        EDGE, "adapt", 0.0)
    assert (edge["progress_uploads"], edge["restore_keyframes"]) == (False, 0)
    assert edge["connected_map"] is False          # the policy's uploads as it chose them
    # the intrinsics every committed figure of the paper's device was made with
    assert paper["sequence_player"]["colour_intrinsics"] == ""


def test_launch_and_evaluate_help_name_the_same_default(
        monkeypatch: pytest.MonkeyPatch) -> None:
    # argparse wraps help at the terminal's width and breaks "paper-table1.yaml" at its
    # hyphen on a narrow one (a clean clone's run without a terminal did): read it unwrapped
    monkeypatch.setenv("COLUMNS", "1000")
    for name in ("launch", "evaluate"):
        text = " ".join(_command(name).format_help().split())
        entry = text[text.index("--map-source"):]
        assert f"default: the parameter file's, which is {EDGE_LOCAL}" in entry or (
            f"default {EDGE_LOCAL}," in entry), f"{name}: {entry[:300]}"
        assert "paper-table1.yaml" in text, name
