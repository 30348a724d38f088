"""tf2 transforms of 4×4 poses: what makes the suite's frames one TF tree in a viewer.

The tree (docs/running.md, "What a viewer shows"): ``world`` → ``map`` (static, from the player: the
device's map frame is its first frame's camera frame, which the ground truth places in the
world) → the camera's frame (the device, per tracked frame). A child has one parent, so the
ground truth stays a path and a pose in ``world`` rather than a second parent of the camera.
"""

from __future__ import annotations

import numpy as np
from geometry_msgs.msg import TransformStamped
from tf2_msgs.msg import TFMessage

from msg_schemas.headers import set_header
from msg_schemas.interfaces import new
from msg_schemas.poses import pose_msg, rigid_matrix


def transform_stamped(parent_from_child: np.ndarray, stamp: float, parent: str, child: str
                      ) -> TransformStamped:
    """``geometry_msgs/TransformStamped`` of ``child`` in ``parent`` (a 4×4 rigid transform
    mapping child coordinates to parent coordinates: a camera-to-map pose for map → camera)."""
    if not parent or not child:
        raise ValueError(f"a transform needs two frame ids, got {parent!r} → {child!r}")
    if parent == child:
        raise ValueError(f"a transform from frame {parent!r} to itself")
    pose = pose_msg(parent_from_child)
    msg = set_header(new(TransformStamped), stamp, parent)
    msg.child_frame_id = child
    msg.transform.translation.x = pose.position.x
    msg.transform.translation.y = pose.position.y
    msg.transform.translation.z = pose.position.z
    msg.transform.rotation = pose.orientation
    return msg


def tf_message(*transforms: TransformStamped) -> TFMessage:
    """One ``/tf`` or ``/tf_static`` sample holding ``transforms``."""
    return TFMessage(transforms=list(transforms))


def transform_matrix(msg: TransformStamped) -> np.ndarray:
    """The 4×4 of a ``TransformStamped`` (parent from child; the quaternion normalised)."""
    t, q = msg.transform.translation, msg.transform.rotation
    return rigid_matrix((t.x, t.y, t.z), (q.x, q.y, q.z, q.w))
