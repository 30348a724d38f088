"""An edge process over its compute budget pauses every device's loop search and place looks,
and takes them back once the load falls: the governor's levels reach each device's map as its
slots report their compute (``compute_budget``; ``edge_mapper.compute_governor``)."""

from __future__ import annotations

import time
from types import SimpleNamespace

import pytest
from rclpy.parameter import Parameter

import edge_mapper.node as edge_node
from edge_mapper.node import EdgeMapperNode
from twinslam.hosts.loopback import LoopbackDomain
from twinslam.node_runtime.session import RosSession

DEVICES = ("ar1", "ar2")


def _report(edge: EdgeMapperNode, clock: list[float], seconds: float, slots: int) -> None:
    """``slots`` half-second slots alternating between the devices, each reporting
    ``seconds`` of slot work, on the node's clock ``clock``."""
    for k in range(slots):
        clock[0] += 0.5
        link = edge.links[DEVICES[k % len(DEVICES)]]
        assert link.spent is not None
        link.spent(seconds)


def test_over_its_budget_every_device_stops_searching_for_loops_until_the_load_falls(
        domain: LoopbackDomain, ros: RosSession, monkeypatch: pytest.MonkeyPatch) -> None:
    edge = EdgeMapperNode(context=ros.context, parameter_overrides=[
        Parameter("devices", value=list(DEVICES)), Parameter("policy", value="lff"),
        Parameter("compute_budget", value=0.5)])
    clock = [1000.0]
    monkeypatch.setattr(edge_node, "time", SimpleNamespace(monotonic=lambda: clock[0],
                                                           perf_counter=time.perf_counter))
    paused = lambda: [link.core.back_end.loop_search_paused  # noqa: E731
                      for link in edge.links.values()]
    try:
        assert paused() == [False, False]
        _report(edge, clock, 0.45, 40)           # 90 % of a core for 20 s
        assert paused() == [True, True]
        _report(edge, clock, 0.05, 40)           # 10 % of a core
        assert paused() == [False, False]
    finally:
        for link in edge.links.values():
            link.close(keep_checkpoint=True)
        edge.destroy_node()


def test_an_edge_that_merges_maps_pauses_its_place_looks_over_its_budget(
        domain: LoopbackDomain, ros: RosSession, monkeypatch: pytest.MonkeyPatch) -> None:
    """With map merging on and loop closing off, the budget's last step is still there: over
    it no device looks for its place in the other devices' maps, below it they look again."""
    edge = EdgeMapperNode(context=ros.context, parameter_overrides=[
        Parameter("devices", value=list(DEVICES)), Parameter("policy", value="lff"),
        Parameter("merge_maps", value=True), Parameter("loop_closing", value=False),
        Parameter("compute_budget", value=0.5)])
    clock = [1000.0]
    monkeypatch.setattr(edge_node, "time", SimpleNamespace(monotonic=lambda: clock[0],
                                                           perf_counter=time.perf_counter))
    try:
        assert edge.merging is not None and edge.merging.looking
        _report(edge, clock, 0.45, 40)           # 90 % of a core for 20 s
        assert not edge.merging.looking
        _report(edge, clock, 0.05, 40)           # 10 % of a core
        assert edge.merging.looking
    finally:
        for link in edge.links.values():
            link.close(keep_checkpoint=True)
        edge.destroy_node()
