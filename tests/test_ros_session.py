"""A process's own rclpy session (monitors, tests, the benches' emulated devices) on either
executor: it takes the samples its node subscribed to — also subscriptions made after the
executor had the node, as ``bench.edge_scaling`` makes its devices' — and refuses an executor
it does not know by name."""

from __future__ import annotations

import io
import sys
import time
from collections.abc import Mapping
from typing import Any

import pytest
from std_msgs.msg import String

from msg_schemas import qos
from twinslam.hosts.loopback import LoopbackDomain
from twinslam.live.monitor import with_info
from twinslam.node_runtime.session import EXECUTORS, RosSession


def _matched_both_ways(publisher: Any, subscription: Any) -> bool:
    """The writer lists the reader and the reader the writer: the two learn of each other one
    after the other, and a volatile reader skips what a writer sent before it matched it."""
    return publisher.get_subscription_count() > 0 and subscription.get_publisher_count() > 0


@pytest.mark.parametrize("executor", sorted(EXECUTORS))
def test_a_session_takes_what_its_node_subscribed_to_on_either_executor(
        domain: LoopbackDomain, executor: str) -> None:
    with RosSession("session_writer") as writer, \
            RosSession("session_reader", executor=executor) as reader:
        got: list[str] = []

        def take(message: String) -> None:
            got.append(message.data)
        subscription = reader.node.create_subscription(String, "chatter", take, qos.PROTOCOL)
        publisher = writer.node.create_publisher(String, "chatter", qos.PROTOCOL)
        assert reader.spin_until(lambda: _matched_both_ways(publisher, subscription), 30.0), \
            "the reader's subscription was never matched"
        for k in range(3):
            publisher.publish(String(data=f"sample {k}"))
        assert reader.spin_until(lambda: len(got) == 3, 30.0), f"took {got}"
        assert got == ["sample 0", "sample 1", "sample 2"]


@pytest.mark.parametrize("executor", sorted(EXECUTORS))
def test_a_callback_that_asks_for_message_info_gets_it_on_either_executor(
        domain: LoopbackDomain, executor: str) -> None:
    """The launcher's monitor times the protocol's samples by their reception (message
    info): rclpy's two executors hand such a callback the info in two different forms."""
    with RosSession("session_writer") as writer, \
            RosSession("session_reader", executor=executor) as reader:
        got: list[tuple[str, int]] = []

        def take(message: String, info: Mapping[str, int]) -> None:
            got.append((message.data, int(info["received_timestamp"])))
        subscription = reader.node.create_subscription(String, "chatter", with_info(take),
                                                       qos.PROTOCOL)
        publisher = writer.node.create_publisher(String, "chatter", qos.PROTOCOL)
        assert reader.spin_until(lambda: _matched_both_ways(publisher, subscription), 30.0), \
            "the reader's subscription was never matched"
        before = time.time_ns()
        publisher.publish(String(data="timed"))
        assert reader.spin_until(lambda: bool(got), 30.0), "nothing taken"
        (data, received), = got
        assert data == "timed" and before <= received <= time.time_ns()


def test_a_session_on_the_events_executor_starts_where_stderr_has_no_file_descriptor(
        domain: LoopbackDomain, monkeypatch: pytest.MonkeyPatch) -> None:
    """A launcher run from a notebook, an IDE's console or a test that captures its output:
    rclpy's EventsExecutor enables faulthandler on sys.stderr as it is made."""
    captured = io.StringIO()
    monkeypatch.setattr(sys, "stderr", captured)
    with RosSession("session_captured", executor="events") as session:
        assert sys.stderr is captured              # the process's stderr lent, then given back
        session.spin_once(0.01)


def test_a_session_refuses_an_executor_it_does_not_know(domain: LoopbackDomain) -> None:
    with pytest.raises(ValueError, match="choose from single, events"):
        RosSession("session_refused", executor="multi")
