"""The device's map source has one default for the product: what a user gets from the node,
from ``twinslam launch`` (the bundled parameter file) and from ``twinslam evaluate`` is the same
device, and each ``--help`` says which."""

from __future__ import annotations

import argparse

import yaml

from device_tracker.parameters import PARAMETERS
from twinslam.cli.main import build_parser
from twinslam.live.launcher import DEFAULT_PARAMS
from twinslam.slam.front_end.map_source import DEFAULT_MAP_SOURCE, EDGE


def _command(name: str) -> argparse.ArgumentParser:
    (sub,) = [a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction)]
    return sub.choices[name]


def _map_source_action(name: str) -> argparse.Action:
    return next(a for a in _command(name)._actions if "--map-source" in a.option_strings)


def test_the_node_the_parameter_file_and_evaluate_default_to_the_papers_device() -> None:
    node_default = next(p.default for p in PARAMETERS if p.name == "map_source")
    params = yaml.safe_load(DEFAULT_PARAMS.read_text())
    file_default = params["device_tracker"]["ros__parameters"]["map_source"]
    assert DEFAULT_MAP_SOURCE == EDGE
    assert (node_default, file_default, _map_source_action("evaluate").default) == (
        EDGE, EDGE, EDGE)


def test_launch_and_evaluate_help_name_the_same_default() -> None:
    for name in ("launch", "evaluate"):
        text = " ".join(_command(name).format_help().split())
        entry = text[text.index("--map-source"):]
        assert f"default: the parameter file's, which is {EDGE}" in entry or (
            f"default {EDGE}," in entry), f"{name}: {entry[:300]}"
