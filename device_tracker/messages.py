"""The device's side of the per-slot protocol as messages (DESIGN.md §1 steps 2 and 4): the slot's
``FrameSummaries`` and the ``Keyframe`` uploads, built from plain arrays. Pure conversion, no
DDS; ``edge_mapper.messages`` reads what this writes.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from msg_schemas import new
from msg_schemas.headers import ros_time, set_header
from msg_schemas.poses import pose_msg


@dataclass(frozen=True)
class FrameRecord:
    """One tracked frame of the slot, as the device remembers it until the slot ends."""

    frame_id: int
    stamp: float                   #: capture time, seconds
    pose: np.ndarray               #: 4×4 camera-to-map estimate
    tracked: bool
    map_point_ids: np.ndarray      #: global ids of the last map update it observes
    track_ids: np.ndarray          #: device-local ids of new features it observes


def frame_summaries_message(slot: int, rate_mbps: float, rate_state: int, map_version: int,
                            frames: list[FrameRecord], stamp: float) -> Any:
    msg = new("twinslam_msgs/msg/FrameSummaries", slot=slot, rate_mbps=rate_mbps,
              rate_state=rate_state, map_version=map_version,
              frames=[new("twinslam_msgs/msg/FrameSummary", frame_id=f.frame_id,
                          stamp=ros_time(f.stamp), pose=pose_msg(f.pose), tracked=f.tracked,
                          map_point_ids=np.asarray(f.map_point_ids, dtype=np.uint64),
                          local_track_ids=np.asarray(f.track_ids, dtype=np.uint64))
                      for f in frames])
    return set_header(msg, stamp, "map")


def keyframe_message(slot: int, frame_id: int, stamp: float, pose: np.ndarray,
                     intrinsics: np.ndarray, keypoints: np.ndarray, depths: np.ndarray,
                     descriptors: np.ndarray, point_ids: np.ndarray,
                     camera_frame: str = "camera", image: Any = None) -> Any:
    """A keyframe: n keypoints, their depths (0 = none), ORB descriptors and the ids they were
    associated with (0 = none, top bit = track id); with ``image`` (a ``sensor_msgs/Image``)
    the frame itself too, otherwise features only."""
    xy = np.asarray(keypoints, dtype=np.float32).reshape(-1, 2)
    n = len(xy)
    desc = np.asarray(descriptors, dtype=np.uint8)
    if desc.shape != (n, 32) or len(depths) != n or len(point_ids) != n:
        raise ValueError(f"frame {frame_id}: {n} keypoints need n×32 descriptors and n depths "
                         f"and ids, got {desc.shape}, {len(depths)}, {len(point_ids)}")
    msg = new("twinslam_msgs/msg/Keyframe", slot=slot, frame_id=frame_id,
              pose_estimate=pose_msg(pose),
              k=np.asarray(intrinsics, dtype=np.float64).reshape(-1),
              keypoints_xy=xy.reshape(-1), keypoint_depths=np.asarray(depths, np.float32),
              descriptors=desc.reshape(-1), map_point_ids=np.asarray(point_ids, np.uint64))
    if image is not None:
        msg.image = image
    return set_header(msg, stamp, camera_frame)
