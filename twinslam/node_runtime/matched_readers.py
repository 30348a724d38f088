"""Protocol endpoints that say when the other side comes and goes.

The protocol's topics are volatile: a sample written before a reader has matched the writer is
never delivered to it. A match is only visible inside each endpoint's own process, and the two
sides match one after the other: a writer may list a reader (it learned of it) before that
reader has matched the writer, and a volatile reader that matches late skips what was written
before (Fast DDS, eProsima/Fast-DDS#2641). So a node logs its endpoints' matches —
``udt/rate_latent: 1 reader(s) matched`` for a writer, ``device/frame_summaries: 1 writer(s)
matched`` for a reader — for an operator checking that the edge listens, and for a test or a
tool that must not publish the first slot into the void (``ProcessDomain.wait_for_log``).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from rclpy.event_handler import PublisherEventCallbacks, SubscriptionEventCallbacks
from rclpy.node import Node

#: what a writer's and a reader's lines count
READERS, WRITERS = "reader(s)", "writer(s)"


def matched_line(topic_name: str, count: int, endpoints: str) -> str:
    """The line logged once ``count`` ``endpoints`` (READERS or WRITERS) matched the endpoint
    of ``topic_name`` (resolved, without its leading slash): what a test or a tool waits for
    in the node's log before it publishes."""
    return f"{topic_name}: {count} {endpoints} matched"


def logging_matches(node: Node, topic: str) -> PublisherEventCallbacks:
    """Event callbacks for ``create_publisher(..., event_callbacks=...)`` that log each change
    in the number of readers matched to the writer of ``topic``. Readers that match at once
    raise one event each, and each event reports the count as it is when the executor takes
    it (eight readers: "8 reader(s) matched" eight times): a count already logged is not
    logged again."""
    return PublisherEventCallbacks(matched=_logging_count(node, topic, READERS))


def logging_writer_matches(node: Node, topic: str) -> SubscriptionEventCallbacks:
    """Event callbacks for ``create_subscription(..., event_callbacks=...)`` that log each
    change in the number of writers matched to the reader of ``topic``, as
    :func:`logging_matches` does for a writer's readers: once it is logged, what a writer
    publishes reaches this reader."""
    return SubscriptionEventCallbacks(matched=_logging_count(node, topic, WRITERS))


def _logging_count(node: Node, topic: str, what: str) -> Callable[[Any], None]:
    """A matched-event callback logging :func:`matched_line` when the count changes."""
    name = node.resolve_topic_name(topic).lstrip("/")
    logged: list[int] = []

    def matched(info: Any) -> None:
        count = int(info.current_count)
        if logged and logged[-1] == count:
            return
        logged[:] = [count]
        node.get_logger().info(matched_line(name, count, what))

    return matched
