"""``--edge NAME=VALUE`` and ``--device NAME=VALUE`` on the in-process benches
(``bench.place_walks``, ``bench.shared_map``): a node parameter reaches the cores as the node
would take it, and one no core reads, or out of its bounds, is refused before anything runs."""

from __future__ import annotations

import argparse
import dataclasses

import pytest

from bench.in_process import (
    EDGE_CORE_PARAMETERS,
    device_parameter,
    edge_parameter,
    repeatable_edge,
)
from edge_mapper.parameters import PARAMETERS as EDGE_PARAMETERS


def _other_value(default: object, low: float | None, high: float | None) -> object:
    """A value of the parameter's kind other than its default, within its bounds."""
    if isinstance(default, bool):
        return not default
    if isinstance(default, int):
        return default - 1 if high is not None and default + 1 > high else default + 1
    if isinstance(default, float):
        half = default / 2 if default else 0.5
        return half if low is None or half >= low else (default + (high or default + 1)) / 2
    raise AssertionError(f"no other value for {default!r}")


def test_every_edge_parameter_the_option_takes_changes_the_edge_cores_configuration() -> None:
    """The option takes the edge parameters the core's configuration is made of, each of them
    changing it: none is taken and then silently left out."""
    assert {"restore_keyframes", "vmax", "covered_by_points"} <= EDGE_CORE_PARAMETERS
    assert "policy" not in EDGE_CORE_PARAMETERS                # the node's, not a core's
    default = repeatable_edge()
    for spec in EDGE_PARAMETERS:
        if spec.name not in EDGE_CORE_PARAMETERS:
            continue
        value = _other_value(spec.default, spec.low, spec.high)
        name, typed = edge_parameter(f"{spec.name}={str(value).lower()}")
        changed = repeatable_edge(**{name: typed})
        assert dataclasses.asdict(changed) != dataclasses.asdict(default), spec.name


def test_an_edge_parameter_no_core_reads_or_out_of_bounds_is_refused() -> None:
    assert edge_parameter("restore_keyframes=6") == ("restore_keyframes", 6)
    restored = dict([edge_parameter("restore_keyframes=6")])
    assert repeatable_edge(**restored).restore_keyframes == 6
    with pytest.raises(argparse.ArgumentTypeError,
                       match=r"an edge parameter the edge's core reads .*restore_keyframes"):
        edge_parameter("policy=lff")
    with pytest.raises(argparse.ArgumentTypeError, match=r"within \[0, 1000\]"):
        edge_parameter("restore_keyframes=-1")
    with pytest.raises(argparse.ArgumentTypeError, match="invalid literal"):
        edge_parameter("vmax=many")
    assert device_parameter("map_source=edge") == ("map_source", "edge")
    with pytest.raises(argparse.ArgumentTypeError, match="a device parameter"):
        device_parameter("vmax=30")
