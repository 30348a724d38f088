"""Subscriptions that decode and validate what they receive before the node's callback sees it.

A :class:`CheckedSubscription` takes each sample as the bytes that came off the wire (rclpy's
raw subscription) and decodes them itself, so that every refusal is the node's own, logged
with its reason and counted: bytes that are not CDR of the topic's type (a truncated sample,
a 4 GB sequence length — Fast DDS would otherwise drop them without a word), and well-formed
CDR whose content is nonsense (an image shorter than ``height × step``, a NaN pose, descriptors
that do not match the keypoint count; :mod:`msg_schemas.validation`, docs/architecture.md §8). The
node goes on with what it had.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from rclpy.node import Node
from rclpy.qos import QoSProfile
from rclpy.serialization import deserialize_message

from msg_schemas.interfaces import type_name_of
from msg_schemas.validation import MessageError, validate


class CheckedSubscription:
    """A subscription whose callback only gets decodable, valid messages; ``received`` and
    ``rejected`` count what arrived."""

    def __init__(self, node: Node, msg_type: type, topic: str,
                 callback: Callable[[Any], None], qos: QoSProfile, **kwargs: Any) -> None:
        self.msg_type = msg_type
        self.type_name = type_name_of(msg_type)
        self.callback = callback
        self.received = 0
        self.rejected = 0
        self._logger = node.get_logger()
        self.subscription = node.create_subscription(msg_type, topic, self._on_data, qos,
                                                     raw=True, **kwargs)
        #: read once: a sample the executor hands over after the subscription was destroyed
        #: (a link the edge closed) must still be named, and the destroyed handle cannot
        self._topic = str(self.subscription.topic_name)

    def _on_data(self, data: bytes) -> None:
        self.handle(data)

    @property
    def topic_name(self) -> str:
        return self._topic

    def get_publisher_count(self) -> int:
        return self.subscription.get_publisher_count()

    def handle(self, data: bytes) -> bool:
        """One sample as serialised on the wire: decoded, validated and given to the
        callback, or rejected with a logged error; returns whether the callback ran."""
        try:
            msg = deserialize_message(data, self.msg_type)
        except Exception as exc:          # rclpy raises its RMW error for bytes it cannot decode
            return self._reject(data, f"not CDR of the type ({exc})")
        try:
            validate(self.type_name, msg)
        except MessageError as exc:
            return self._reject(data, str(exc))
        self.received += 1
        self.callback(msg)
        return True

    def _reject(self, data: bytes, reason: str) -> bool:
        self.rejected += 1
        self._logger.error(f"dropped a malformed {self.type_name} on {self.topic_name} "
                           f"({len(data)} bytes): {reason}")
        return False
