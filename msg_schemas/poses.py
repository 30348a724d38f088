"""``geometry_msgs/Pose`` ↔ 4×4 homogeneous matrix (camera-to-map by the project's convention)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from geometry_msgs.msg import Pose

from msg_schemas.interfaces import new
from twinslam.rotations import matrix_from_quaternion, quaternion_from_matrix


def pose_msg(matrix: np.ndarray) -> Pose:
    """A ``geometry_msgs/Pose`` of a 4×4 rigid transform."""
    m = np.asarray(matrix, dtype=np.float64)
    qx, qy, qz, qw = (float(v) for v in quaternion_from_matrix(m[:3, :3]))
    msg = new(Pose)
    msg.position.x, msg.position.y, msg.position.z = (float(v) for v in m[:3, 3])
    msg.orientation.x, msg.orientation.y, msg.orientation.z, msg.orientation.w = qx, qy, qz, qw
    return msg


def pose_matrix(msg: Pose) -> np.ndarray:
    """The 4×4 transform of a ``geometry_msgs/Pose`` (the quaternion is normalised)."""
    q, t = msg.orientation, msg.position
    return rigid_matrix((t.x, t.y, t.z), (q.x, q.y, q.z, q.w))


def rigid_matrix(translation: Sequence[float], quaternion_xyzw: Sequence[float]) -> np.ndarray:
    """The 4×4 of a translation and a quaternion in ROS order (x, y, z, w; normalised here)."""
    out = np.eye(4)
    out[:3, :3] = matrix_from_quaternion(quaternion_xyzw)
    out[:3, 3] = translation
    return out
