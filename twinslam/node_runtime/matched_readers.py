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
    in the number of readers matched to the writer of ``topic``."""
    name = node.resolve_topic_name(topic).lstrip("/")

    def matched(info: QoSPublisherMatchedInfo) -> None:
        node.get_logger().info(f"{name}: {info.current_count} reader(s) matched")

    return PublisherEventCallbacks(matched=matched)
