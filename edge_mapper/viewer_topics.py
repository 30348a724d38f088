"""One device's viewer topics on the edge (its map's cloud, its keyframes, the slot's
decisions and the keyframe trajectory), each built only while a subscription listens to it.

Each of these messages is made from the whole map at every slot's end — ~4 ms a device-slot
on the 7-Scenes walk (``bench.edge_work``'s "viewer out"), ~13 ms a trajectory of 545
keyframes — on the one thread that serves every device of the edge, for topics that an edge
serving a fleet mostly has no viewer on. A topic's message is therefore made only when DDS
has matched a subscription to it (RViz, Foxglove's bridge, ``ros2 bag record`` and the run's
monitor all subscribe), as drivers do for their costly outputs. The topics are latched: a
viewer that joins gets the last message sent at once and the map as it is at the next slot's
end. The trajectory goes out every ``trajectory_every`` slots and after a loop; one due while
nobody listened is owed, and sent at the first slot's end that finds a subscriber.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence

import numpy as np
from geometry_msgs.msg import PoseArray
from nav_msgs.msg import Path as PathMsg
from rclpy.node import Node
from rclpy.publisher import Publisher
from sensor_msgs.msg import PointCloud2
from visualization_msgs.msg import MarkerArray

from edge_mapper.visual_messages import (
    decisions_message,
    keyframe_trajectory_message,
    keyframes_message,
    map_points_message,
)
from msg_schemas import qos, topics
from twinslam.slam.back_end.keyframe_map import KeyFrameMap

#: (capture time s, camera-to-map pose) of every keyframe kept, made only when sent
Trajectory = Callable[[], Sequence[tuple[float, np.ndarray]]]


class ViewerTopics:
    """The four latched viewer publishers of one device (``topic`` maps a topic name to the
    device's), and what was skipped for want of a subscriber."""

    def __init__(self, node: Node, topic: Callable[[str], str], trajectory_every: int) -> None:
        pub = node.create_publisher
        self.cloud = pub(PointCloud2, topic(topics.MAP_POINTS), qos.MAP)
        self.keyframes = pub(PoseArray, topic(topics.KEYFRAME_POSES), qos.MAP)
        self.decisions = pub(MarkerArray, topic(topics.DECISIONS), qos.MAP)
        self.trajectory = pub(PathMsg, topic(topics.KEYFRAME_TRAJECTORY), qos.MAP)
        self.trajectory_every = trajectory_every
        #: a trajectory was due while nobody listened (the first is due at once, unless the
        #: trajectory goes out after loops only)
        self.trajectory_owed = trajectory_every > 0
        self.skipped = 0                       #: messages not made: nobody subscribed

    @property
    def publishers(self) -> tuple[Publisher, ...]:
        return self.cloud, self.keyframes, self.decisions, self.trajectory

    def wants_decisions(self) -> bool:
        """Whether the slot's decisions will be sent: the caller then notes where the map's
        keyframes stood before the slot's end (the evicted ones are drawn there)."""
        return self.decisions.get_subscription_count() > 0

    def publish(self, m: KeyFrameMap, slot: int, stamp: float, frame_id: str,
                integrated: list[int], evicted: list[int], restored: Sequence[int],
                poses_before: Mapping[int, np.ndarray], loop_closed: bool,
                trajectory: Trajectory) -> None:
        """The slot's messages, each to the topics someone listens to: the map's points and
        keyframes, the decisions (``poses_before``: where the evicted keyframes were) and,
        when due (a loop closed, every ``trajectory_every`` slots) or owed, the trajectory."""
        for publisher, make in (
                (self.cloud, lambda: map_points_message(m, stamp, frame_id)),
                (self.keyframes, lambda: keyframes_message(m, stamp, frame_id)),
                (self.decisions, lambda: decisions_message(m, integrated, evicted, poses_before,
                                                           stamp, frame_id, restored))):
            if publisher.get_subscription_count() > 0:
                publisher.publish(make())
            else:
                self.skipped += 1
        every = self.trajectory_every
        due = loop_closed or (every > 0 and slot % every == 0)
        if not (due or self.trajectory_owed):
            return
        if self.trajectory.get_subscription_count() > 0:
            self.trajectory.publish(keyframe_trajectory_message(trajectory(), stamp, frame_id))
            self.trajectory_owed = False
        else:
            self.skipped += 1
            self.trajectory_owed = True

    def destroy(self, node: Node) -> None:
        for publisher in self.publishers:
            node.destroy_publisher(publisher)
