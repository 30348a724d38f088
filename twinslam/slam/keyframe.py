"""A keyframe as the uplink carries it: one payload type for the device that sends it and the
edge that integrates it, and the one conversion to and from ``twinslam_msgs/Keyframe``.

The device fills it from a tracked frame (features, their depths, the id each feature
observes), the edge reads it back to associate and create map points. Feature ids share one
64-bit space: a map point's global id, or a device-local track id with :data:`TRACK_ID_BIT`
set, or 0 for a feature associated with nothing.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from twinslam_msgs.msg import Keyframe

from msg_schemas import new
from msg_schemas.headers import set_header, stamp_seconds
from msg_schemas.poses import pose_matrix, pose_msg
from msg_schemas.validation import ORB_DESCRIPTOR_BYTES

TRACK_ID_BIT = np.uint64(1 << 63)          #: marks a device-local track id


@dataclass(frozen=True)
class KeyFramePayload:
    """What a ``Keyframe`` message carries for one frame, as arrays."""

    frame_id: int
    slot: int
    stamp: float                   #: capture time, seconds
    pose: np.ndarray               #: 4×4 camera-to-map (the device's estimate)
    intrinsics: np.ndarray         #: 3×3
    keypoints: np.ndarray          #: n×2 float32
    depths: np.ndarray             #: n float32, metres, 0 = none
    descriptors: np.ndarray        #: n×32 uint8
    point_ids: np.ndarray          #: n uint64: global id, TRACK_ID_BIT | track id, or 0


def keyframe_message(payload: KeyFramePayload, camera_frame: str = "camera",
                     image: object | None = None) -> Keyframe:
    """The ``Keyframe`` of a payload; with ``image`` (a ``sensor_msgs/Image``) the frame
    itself too, otherwise features only. Inconsistent array sizes are refused (ValueError)
    here, before anything is sent."""
    xy = np.asarray(payload.keypoints, dtype=np.float32).reshape(-1, 2)
    n = len(xy)
    desc = np.asarray(payload.descriptors, dtype=np.uint8)
    if (desc.shape != (n, ORB_DESCRIPTOR_BYTES) or len(payload.depths) != n
            or len(payload.point_ids) != n):
        raise ValueError(f"frame {payload.frame_id}: {n} keypoints need n×"
                         f"{ORB_DESCRIPTOR_BYTES} descriptors and n depths and ids, got "
                         f"{desc.shape}, {len(payload.depths)}, {len(payload.point_ids)}")
    msg = new(Keyframe, slot=payload.slot, frame_id=payload.frame_id,
              pose_estimate=pose_msg(payload.pose),
              k=np.asarray(payload.intrinsics, dtype=np.float64).reshape(-1),
              keypoints_xy=xy.reshape(-1),
              keypoint_depths=np.asarray(payload.depths, np.float32),
              descriptors=desc.reshape(-1),
              map_point_ids=np.asarray(payload.point_ids, np.uint64))
    if image is not None:
        msg.image = image
    return set_header(msg, payload.stamp, camera_frame)


def read_keyframe(msg: Keyframe) -> KeyFramePayload:
    """Unpack a (validated) ``Keyframe``; depths or ids missing altogether read as zeros."""
    xy = np.asarray(msg.keypoints_xy, dtype=np.float32).reshape(-1, 2)
    n = len(xy)
    depths = np.asarray(msg.keypoint_depths, dtype=np.float32)
    ids = np.asarray(msg.map_point_ids, dtype=np.uint64)
    return KeyFramePayload(
        int(msg.frame_id), int(msg.slot), stamp_seconds(msg.header),
        pose_matrix(msg.pose_estimate), np.asarray(msg.k, dtype=np.float64).reshape(3, 3), xy,
        depths if depths.size == n else np.zeros(n, np.float32),
        np.asarray(msg.descriptors, dtype=np.uint8).reshape(n, ORB_DESCRIPTOR_BYTES),
        ids if ids.size == n else np.zeros(n, np.uint64))
