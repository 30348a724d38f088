"""A listener node run as its own OS process by the cross-process tests.

It subscribes to one topic (parameters ``topic`` and ``type``) through a
:class:`~twinslam.node_runtime.checked_subscription.CheckedSubscription`, prints one JSON line when
it is
ready (its resolved names and parameters), one each time the writers matched to its reader
change, and one per message it accepts, holding the digest of its content
(:mod:`tests.nodes.digest`).
"""

from __future__ import annotations

import json
import sys
from typing import Any

from rclpy.event_handler import SubscriptionEventCallbacks
from rclpy.node import Node

from msg_schemas import message_class, qos
from tests.nodes.digest import content_digest
from twinslam.node_runtime.checked_subscription import CheckedSubscription
from twinslam.node_runtime.node_main import run_node


class Listener(Node):
    def __init__(self) -> None:
        super().__init__("listener")
        topic = self.declare_parameter("topic", "chatter").value
        self.type_name = self.declare_parameter("type", "std_msgs/msg/String").value
        qos_name = self.declare_parameter("qos", "default").value
        extra = self.declare_parameter("extra", "none").value
        profile = qos.SENSOR_DATA if qos_name == "sensor_data" else qos.PROTOCOL
        self.sub = CheckedSubscription(
            self, message_class(self.type_name), topic, self.on_msg, profile,
            event_callbacks=SubscriptionEventCallbacks(matched=self.on_matched))
        print(json.dumps({"event": "ready", "name": self.get_name(),
                          "namespace": self.get_namespace(), "topic": self.sub.topic_name,
                          "extra": extra}), flush=True)

    def on_matched(self, info: Any) -> None:
        """One line each time the writers matched to the reader change: a test's writer
        publishes once this says 1 (before, a volatile reader would skip its samples)."""
        print(json.dumps({"event": "matched", "writers": int(info.current_count)}), flush=True)

    def on_msg(self, msg: object) -> None:
        print(json.dumps({"event": "msg", "type": self.type_name,
                          "digest": content_digest(msg)}),
              flush=True)


if __name__ == "__main__":
    sys.exit(run_node("listener", Listener))
