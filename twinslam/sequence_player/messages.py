"""RgbdFrame → ROS 2 messages (sensor_msgs/Image, CameraInfo, geometry_msgs/PoseStamped).

Pure conversion, no DDS: the node publishes what these return, and a recorder can write the
same messages to a bag.
"""

from __future__ import annotations

import numpy as np
from geometry_msgs.msg import PoseStamped
from sensor_msgs.msg import CameraInfo, Image

from msg_schemas import new
from msg_schemas.headers import set_header
from msg_schemas.poses import pose_msg
from twinslam.sequences.frame import RgbdFrame

DEPTH_ENCODINGS = ("16UC1", "32FC1")


def color_message(frame: RgbdFrame, stamp: float, frame_id: str, mono: bool = False) -> Image:
    """``rgb8`` (or ``mono8``) image of the frame's colour."""
    if mono:
        gray = (frame.color @ np.array([0.299, 0.587, 0.114])).round().astype(np.uint8)
        data, encoding, channels = gray, "mono8", 1
    else:
        data, encoding, channels = frame.color, "rgb8", 3
    h, w = data.shape[:2]
    msg = new(Image, height=h, width=w, encoding=encoding,
              step=w * channels, data=np.ascontiguousarray(data).reshape(-1))
    return set_header(msg, stamp, frame_id)


def depth_message(frame: RgbdFrame, stamp: float, frame_id: str, encoding: str = "16UC1"
                  ) -> Image:
    """Depth as ``16UC1`` millimetres (0 = no reading) or ``32FC1`` metres (NaN = none), the
    two REP 118 encodings."""
    if frame.depth is None:
        raise ValueError(f"{frame.name}: the frame has no depth")
    if encoding == "16UC1":
        data = np.clip(np.round(frame.depth * 1000.0), 0, 65535).astype(np.uint16)
        bpp = 2
    elif encoding == "32FC1":
        data = np.where(frame.depth > 0, frame.depth, np.nan).astype(np.float32)
        bpp = 4
    else:
        raise ValueError(f"depth encoding must be one of {DEPTH_ENCODINGS}, got {encoding!r}")
    h, w = data.shape
    msg = new(Image, height=h, width=w, encoding=encoding, step=w * bpp,
              data=np.ascontiguousarray(data).view(np.uint8).reshape(-1))
    return set_header(msg, stamp, frame_id)


def camera_info_message(frame: RgbdFrame, stamp: float, frame_id: str) -> CameraInfo:
    """Pinhole CameraInfo (no distortion; the datasets ship rectified images)."""
    k = np.asarray(frame.intrinsics, dtype=np.float64)
    p = np.zeros((3, 4))
    p[:, :3] = k
    h, w = frame.color.shape[:2]
    msg = new(CameraInfo, height=h, width=w, distortion_model="plumb_bob",
              d=np.zeros(5), k=k.reshape(-1), r=np.eye(3).reshape(-1), p=p.reshape(-1))
    return set_header(msg, stamp, frame_id)


def pose_message(pose: np.ndarray, stamp: float, frame_id: str) -> PoseStamped:
    """Camera-to-world 4×4 as a PoseStamped in ``frame_id`` (the world frame)."""
    msg = new(PoseStamped, pose=pose_msg(pose))
    return set_header(msg, stamp, frame_id)
