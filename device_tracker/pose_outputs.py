"""What a viewer sees of the device's poses: ``device/pose`` every frame, ``device/path`` (the
newest ``path_window`` poses) every slot, and ``map`` → camera on ``/tf`` for every tracked
frame — an untracked pose is only a guess, so it is published as a pose but never as a
transform. The camera's frame id is the images' unless ``camera_frame`` names one; when it is
the map's own frame the transform would be a loop, so the broadcast stops and says why."""

from __future__ import annotations

import numpy as np
from geometry_msgs.msg import PoseStamped
from nav_msgs.msg import Path
from rclpy.node import Node
from tf2_msgs.msg import TFMessage

from device_tracker.parameters import DeviceSettings
from msg_schemas import qos, topics
from msg_schemas.headers import set_header
from msg_schemas.paths import PathWindow
from msg_schemas.poses import pose_msg
from msg_schemas.transforms import tf_message, transform_stamped


class PoseOutputs:
    """The device's pose, path and transform publishers on ``node``."""

    def __init__(self, node: Node, settings: DeviceSettings) -> None:
        self.node, self.settings = node, settings
        self.path = PathWindow(settings.path_window)
        self.pub_pose = node.create_publisher(PoseStamped, topics.DEVICE_POSE, qos.PROTOCOL)
        self.pub_path = node.create_publisher(Path, topics.DEVICE_PATH, qos.MAP)
        self.pub_tf = (node.create_publisher(TFMessage, topics.TF, qos.TF)
                       if settings.publish_tf else None)

    def frame(self, pose: np.ndarray, tracked: bool, stamp: float, image_frame: str) -> None:
        """One frame's pose (camera-to-map), published and kept for the path."""
        msg = set_header(PoseStamped(pose=pose_msg(pose)), stamp, self.settings.map_frame)
        self.pub_pose.publish(msg)
        if self.pub_tf is not None and tracked:
            self._broadcast(pose, stamp, image_frame)
        self.path.add(msg)

    def slot_end(self, stamp: float) -> None:
        """The path as it stands at a slot's end."""
        self.pub_path.publish(self.path.message(stamp, self.settings.map_frame))

    def _broadcast(self, pose: np.ndarray, stamp: float, image_frame: str) -> None:
        assert self.pub_tf is not None
        s = self.settings
        child = s.camera_frame or image_frame or "camera"
        if child == s.map_frame:
            self.node.get_logger().error(f"the camera images are in frame {child!r}, the "
                                         "device's map frame: no transform on /tf (set "
                                         "camera_frame)")
            self.node.destroy_publisher(self.pub_tf)
            self.pub_tf = None
            return
        self.pub_tf.publish(tf_message(transform_stamped(pose, stamp, s.map_frame, child)))
