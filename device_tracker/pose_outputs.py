"""What a viewer sees of the device's poses: ``device/pose`` (in ``map``) every frame,
``device/path`` (the newest ``path_window`` poses) every slot, and on ``/tf`` for every tracked
frame REP 105's ``map`` → ``odom`` → camera (:mod:`device_tracker.odometry_frame`: the
corrections of the map pose go to ``map → odom``, the device's own motion to ``odom →
camera``), with ``device/odom`` the camera in ``odom`` every frame. An untracked pose is only a
guess, so it is published as a pose but never as a transform. The camera's frame id is the
images' unless ``camera_frame`` names one; when it is the map's own frame the transform would
be a loop, so the broadcast stops and says why. ``odom_frame`` empty: ``map`` → camera
directly, as before REP 105. A device whose map joined another device's place publishes in
that place's frame from the first pose tracked on the merged map on
(:mod:`device_tracker.map_frame_name`): its path starts again there, its poses before being in
the frame it left."""

from __future__ import annotations

from geometry_msgs.msg import PoseStamped
from nav_msgs.msg import Odometry, Path
from rclpy.node import Node
from tf2_msgs.msg import TFMessage

from device_tracker.messages import FrameRecord
from device_tracker.odometry_frame import OdometryFrame
from device_tracker.parameters import DeviceSettings
from msg_schemas import qos, topics
from msg_schemas.headers import set_header
from msg_schemas.paths import PathWindow
from msg_schemas.poses import pose_msg
from msg_schemas.transforms import tf_message, transform_stamped


class PoseOutputs:
    """The device's pose, odometry, path and transform publishers on ``node``."""

    def __init__(self, node: Node, settings: DeviceSettings) -> None:
        self.node, self.settings = node, settings
        self.path = PathWindow(settings.path_window)
        self.pub_pose = node.create_publisher(PoseStamped, topics.DEVICE_POSE, qos.PROTOCOL)
        self.pub_path = node.create_publisher(Path, topics.DEVICE_PATH, qos.MAP)
        self.odometry = OdometryFrame() if settings.odom_frame else None
        self.pub_odom = (node.create_publisher(Odometry, topics.DEVICE_ODOM, qos.PROTOCOL)
                         if self.odometry is not None else None)
        self.pub_tf = (node.create_publisher(TFMessage, topics.TF, qos.TF)
                       if settings.publish_tf else None)
        #: the frame the newest pose went out in
        self.map_frame = settings.map_frame

    def frame(self, record: FrameRecord, stamp: float, image_frame: str, frame: str) -> None:
        """One frame's pose (camera-to-map ``frame``: the frame of the map it was tracked on,
        :class:`~device_tracker.map_frame_name.MapFrameName`), published, kept for the path,
        and split into ``map → odom → camera``."""
        s = self.settings
        if frame != self.map_frame:
            self.node.get_logger().info(f"poses in {frame} from map version "
                                        f"{record.map_version} on (they were in "
                                        f"{self.map_frame}): the edge's map update is in "
                                        "that frame")
            self.map_frame = frame
            self.path = PathWindow(s.path_window)
        msg = set_header(PoseStamped(pose=pose_msg(record.pose)), stamp, frame)
        self.pub_pose.publish(msg)
        self.path.add(msg)
        child = s.camera_frame or image_frame or "camera"
        # the transforms down to the camera: (parent from child, parent, child)
        chain = [(record.pose, frame, child)]
        if self.odometry is not None and self.pub_odom is not None:
            odom, map_from_odom = self.odometry.update(record.pose, record.tracked,
                                                       record.map_version, record.relocalised)
            odometry = set_header(Odometry(child_frame_id=child), stamp, s.odom_frame)
            odometry.pose.pose = pose_msg(odom)
            self.pub_odom.publish(odometry)
            chain = [(map_from_odom, frame, s.odom_frame), (odom, s.odom_frame, child)]
        if record.tracked and self._may_broadcast(child):
            assert self.pub_tf is not None
            self.pub_tf.publish(tf_message(*(transform_stamped(pose, stamp, parent, name)
                                             for pose, parent, name in chain)))

    def slot_end(self, stamp: float) -> None:
        """The path as it stands at a slot's end."""
        self.pub_path.publish(self.path.message(stamp, self.map_frame))

    def _may_broadcast(self, child: str) -> bool:
        """Whether the camera's transforms can go on /tf: a camera frame that is the map's
        (or odom's) own would make a loop, so the broadcast stops for good, saying why."""
        if self.pub_tf is None:
            return False
        if child in (self.map_frame, self.settings.odom_frame):
            self.node.get_logger().error(f"the camera images are in frame {child!r}, the "
                                         "device's map or odom frame: no transform on /tf "
                                         "(set camera_frame)")
            self.node.destroy_publisher(self.pub_tf)
            self.pub_tf = None
            return False
        return True

