"""An edge process over its compute budget pauses every device's loop search and place looks,
and takes them back once the load falls: the governor's levels reach each device's map as its
slots report their compute (``compute_budget``; ``edge_mapper.compute_governor``); and it says
so on /diagnostics, where ROS tools look."""

from __future__ import annotations

import sys
import time
from types import SimpleNamespace

import pytest
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rclpy.parameter import Parameter

import edge_mapper.node as edge_node
from edge_mapper.node import EdgeMapperNode
from msg_schemas import qos, topics
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


def test_the_edge_tells_its_load_on_diagnostics_and_warns_while_trimmed_or_late(
        domain: LoopbackDomain, ros: RosSession, monkeypatch: pytest.MonkeyPatch) -> None:
    """Each period the edge publishes "<node>: load" on /diagnostics: OK while it keeps up;
    WARN while its budget trims its work, or for a map later than its device's slot, with
    the slots, their latency and the threads' shares of a core as values."""
    heard: list[DiagnosticArray] = []
    ros.node.create_subscription(DiagnosticArray, topics.DIAGNOSTICS, heard.append,
                                 qos.PROTOCOL)
    edge = EdgeMapperNode(context=ros.context, parameter_overrides=[
        Parameter("devices", value=list(DEVICES)), Parameter("policy", value="lff"),
        Parameter("compute_budget", value=0.5), Parameter("diagnostics_period_s", value=0.2)])
    clock = [1000.0]
    monkeypatch.setattr(edge_node, "time", SimpleNamespace(monotonic=lambda: clock[0],
                                                           perf_counter=time.perf_counter))
    ros.executor.add_node(edge)

    def loads() -> list[DiagnosticStatus]:
        return [s for msg in heard for s in msg.status if s.name == "/edge_mapper: load"]

    try:
        for link in edge.links.values():
            assert link.answered is not None
            link.answered(0.3, 1.0)
        calm = edge.publish_load().status[0]
        assert calm.level == DiagnosticStatus.OK
        values = {kv.key: kv.value for kv in calm.values}
        assert (values["devices"], values["slots_answered"], values["slots_late"]) == \
            ("2", "2", "0")
        if sys.platform.startswith("linux"):         # the slot thread's share of a core
            assert "cores main" in values
        _report(edge, clock, 0.45, 40)                 # 90 % of a core for 20 s
        edge.links["ar1"].answered(1.6, 1.0)           # one map 1.6 s after its summaries
        loaded = edge.publish_load().status[0]
        assert loaded.level == DiagnosticStatus.WARN
        assert "over its compute budget" in loaded.message
        assert "1 of 1 maps later than their slot" in loaded.message
        # and the timer publishes it where ROS tools listen
        assert ros.spin_until(lambda: bool(loads()), 30.0)
    finally:
        ros.executor.remove_node(edge)
        for link in edge.links.values():
            link.close(keep_checkpoint=True)
        edge.destroy_node()
