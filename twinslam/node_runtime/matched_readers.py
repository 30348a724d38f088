"""A protocol writer that says when its readers come and go.

The protocol's topics are volatile: a sample written before a reader has matched the writer is
never delivered to it. A writer's match is only visible inside the writer's own process, so a
node logs it — ``udt/rate_latent: 1 reader(s) matched`` — for an operator checking that the edge
listens, and for a test or a tool that must not publish the first slot into the void
(``ProcessDomain.wait_for_log``).
"""

from __future__ import annotations

from rclpy.event_handler import PublisherEventCallbacks, QoSPublisherMatchedInfo
from rclpy.node import Node


def logging_matches(node: Node, topic: str) -> PublisherEventCallbacks:
    """Event callbacks for ``create_publisher(..., event_callbacks=...)`` that log each change
    in the number of readers matched to the writer of ``topic``. Readers that match at once
    raise one event each, and each event reports the count as it is when the executor takes
    it (eight readers: "8 reader(s) matched" eight times): a count already logged is not
    logged again."""
    name = node.resolve_topic_name(topic).lstrip("/")
    logged: list[int] = []

    def matched(info: QoSPublisherMatchedInfo) -> None:
        count = int(info.current_count)
        if logged and logged[-1] == count:
            return
        logged[:] = [count]
        node.get_logger().info(f"{name}: {count} reader(s) matched")

    return PublisherEventCallbacks(matched=matched)
