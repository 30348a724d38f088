"""When a lost device asks the edge to relocalise it, and what it sends.

The device relocalises itself against the map it holds; a place the edge evicted is not in
it, and only the edge's archive remembers it (:mod:`twinslam.slam.back_end.archive_relocalisation`).
While lost, the device sends its newest lost frame's ORB features — keypoints and
descriptors, no image: ~40 kB for 1000 features — at most every ``period_s`` of frame stamps
(Edge-SLAM's device sends a frame every 500 ms); off by default, as the edge's side is (see
``reloc_restore_keyframes``). A request goes up the same uplink as the keyframes: queued on the
upload thread behind the keyframes asked for before it, paced by the shaper at the slot's rate
(an outage sends none), and counted in the next slot's ``UplinkThroughput.request_bytes``
(:meth:`device_tracker.uplink_sender.UplinkSender.carry`). The edge answers on
``edge/relocalisation``; a place it finds comes back with the slot's map update, against which
the device relocalises.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from rclpy.node import Node
from rclpy.serialization import serialize_message
from twinslam_msgs.msg import Relocalisation, RelocalisationRequest

from device_tracker.uplink_sender import Carried, UplinkSender
from msg_schemas import new, qos, topics
from msg_schemas.headers import set_header
from twinslam.node_runtime.checked_subscription import CheckedSubscription
from twinslam.slam.keyframe import KeyFramePayload


class RelocalisationPacer:
    """Says which lost frames to send: the first of a loss, then one every ``period_s``
    seconds of stamps (0: none)."""

    def __init__(self, period_s: float) -> None:
        if period_s < 0:
            raise ValueError(f"reloc_period_s must be >= 0, got {period_s}")
        self.period_s = period_s
        self._last: float | None = None     #: stamp of the last request of this loss

    def due(self, tracked: bool, stamp: float) -> bool:
        """Whether the frame of ``stamp`` (``tracked`` or not) is sent for relocalisation."""
        if tracked or self.period_s <= 0:
            self._last = None
            return False
        if self._last is not None and stamp - self._last < self.period_s:
            return False
        self._last = stamp
        return True


def relocalisation_request_message(frame: KeyFramePayload, stamp: float, camera_frame: str
                                   ) -> RelocalisationRequest:
    """The request for a lost frame: its features as the device holds them for an upload."""
    msg = new(RelocalisationRequest, slot=frame.slot, frame_id=frame.frame_id,
              k=np.asarray(frame.intrinsics, dtype=np.float64).ravel(),
              keypoints_xy=np.asarray(frame.keypoints, dtype=np.float32).ravel(),
              descriptors=np.ascontiguousarray(frame.descriptors, dtype=np.uint8).ravel())
    return set_header(msg, stamp, camera_frame)


class EdgeRelocalisation:
    """The device node's requests to the edge (up ``uplink``, at the rate of the slot
    ``last_slot()`` says ended last) and its answers (``node``'s topics)."""

    def __init__(self, node: Node, period_s: float, uplink: UplinkSender,
                 last_slot: Callable[[], int]) -> None:
        self.node, self.uplink, self.last_slot = node, uplink, last_slot
        self.pacer = RelocalisationPacer(period_s)
        self.publisher = node.create_publisher(RelocalisationRequest,
                                               topics.RELOCALISATION_REQUEST, qos.PROTOCOL)
        self.answers = CheckedSubscription(node, Relocalisation, topics.RELOCALISATION,
                                           self._on_answer, qos.PROTOCOL)

    def due(self, tracked: bool, stamp: float) -> bool:
        return self.pacer.due(tracked, stamp)

    def ask(self, frame: KeyFramePayload | None, stamp: float, camera_frame: str) -> None:
        """Send the lost ``frame`` (None: no longer held, nothing to send)."""
        if frame is not None and len(frame.keypoints):
            msg = relocalisation_request_message(frame, stamp, camera_frame)
            self.uplink.carry(Carried(self.last_slot(), serialize_message(msg),
                                      self.publisher.publish,
                                      f"relocalisation request (frame {frame.frame_id})"))

    def _on_answer(self, msg: Relocalisation) -> None:
        if msg.found:
            self.node.get_logger().info(
                f"frame {msg.frame_id}: the edge found it in its archive ({msg.inliers} "
                "inliers); relocalising against the map update that brings that place back")
