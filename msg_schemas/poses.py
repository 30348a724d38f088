"""``geometry_msgs/Pose`` ↔ 4×4 homogeneous matrix (camera-to-map by the project's convention)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from geometry_msgs.msg import Pose

from msg_schemas.interfaces import new
from twinslam.rotations import matrix_from_quaternion, quaternions_from_matrices


def pose_msg(matrix: np.ndarray) -> Pose:
    """A ``geometry_msgs/Pose`` of a 4×4 rigid transform."""
    return pose_msgs(np.asarray(matrix).reshape(1, 4, 4))[0]


def pose_msgs(matrices: np.ndarray | Sequence[np.ndarray]) -> list[Pose]:
    """:func:`pose_msg` of each 4×4 transform, the rotations converted at once (a map
    update carries every kept keyframe's pose)."""
    m = np.asarray(matrices, dtype=np.float64).reshape(-1, 4, 4)
    if not len(m):
        return []
    quaternions = quaternions_from_matrices(m[:, :3, :3]).tolist()
    out = []
    for (x, y, z), (qx, qy, qz, qw) in zip(m[:, :3, 3].tolist(), quaternions, strict=True):
        msg = new(Pose)
        msg.position.x, msg.position.y, msg.position.z = x, y, z
        msg.orientation.x, msg.orientation.y, msg.orientation.z, msg.orientation.w = \
            qx, qy, qz, qw
        out.append(msg)
    return out


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
