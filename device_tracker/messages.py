"""The device's side of the per-slot protocol as messages (docs/architecture.md §1 steps 2, 4
and 6): the slot's ``FrameSummaries`` and the ``Keyframe`` uploads built from plain arrays, and
the edge's ``MapUpdate`` read into a :class:`~twinslam.slam.map_update.MapSnapshot`. Pure
conversion, no DDS.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
from rclpy.serialization import serialize_message
from twinslam_msgs.msg import FrameSummaries, FrameSummary, Keyframe, MapUpdate, UplinkThroughput

from device_tracker.uplink_sender import Encoded
from msg_schemas import new
from msg_schemas.headers import ros_time, set_header
from msg_schemas.poses import pose_matrix, pose_msg
from msg_schemas.validation import ORB_DESCRIPTOR_BYTES
from twinslam.slam.keyframe import KeyFramePayload
from twinslam.slam.map_update import MapSnapshot
from twinslam.uplink.shaper import SlotThroughput


@dataclass(frozen=True)
class FrameRecord:
    """One tracked frame of the slot, as the device remembers it until the slot ends."""

    frame_id: int
    stamp: float                   #: capture time, seconds
    pose: np.ndarray               #: 4×4 camera-to-map estimate
    tracked: bool
    map_point_ids: np.ndarray      #: global ids of the last map update it observes
    track_ids: np.ndarray          #: device-local ids of new features it observes
    slot: int                      #: the slot its stamp falls in (:mod:`.slot_clock`)
    relocalised: bool = False      #: tracked again only by relocalisation (after a loss)
    inliers: int = 0               #: matches its pose was solved with (0: not tracked)
    map_version: int = 0           #: the map update it was tracked against (0: none yet)
    #: CPU milliseconds the device spent on it: its tracking, and the map updates applied since
    #: the frame before (they run on another thread, between frames)
    cpu_ms: float = 0.0
    #: a pose solved for it was refused by a gate (an impossible motion, or a relocalisation
    #: the pose gate refused): not tracked
    pose_refused: bool = False
    #: its pose came from PnP RANSAC: the motion model's refinement kept too few of its
    #: matches against the map
    pnp_ransac: bool = False
    #: its features matched to map points before the pose solve (``inliers`` are of these)
    matches: int = 0


def frame_summaries_message(slot: int, rate_mbps: float, rate_state: int, map_version: int,
                            frames: list[FrameRecord], stamp: float) -> FrameSummaries:
    msg = new(FrameSummaries, slot=slot, rate_mbps=rate_mbps,
              rate_state=rate_state, map_version=map_version,
              frames=[new(FrameSummary, frame_id=f.frame_id,
                          stamp=ros_time(f.stamp), pose=pose_msg(f.pose), tracked=f.tracked,
                          map_point_ids=np.asarray(f.map_point_ids, dtype=np.uint64),
                          local_track_ids=np.asarray(f.track_ids, dtype=np.uint64),
                          relocalised=f.relocalised, inliers=f.inliers,
                          map_version=f.map_version, cpu_ms=f.cpu_ms,
                          pose_refused=f.pose_refused, pnp_ransac=f.pnp_ransac,
                          matches=f.matches)
                      for f in frames])
    return set_header(msg, stamp, "map")


def uplink_throughput_message(throughput: SlotThroughput, stamp: float) -> UplinkThroughput:
    """What the uplink carried in a slot, as the edge and the twin read it."""
    t = throughput
    msg = new(UplinkThroughput, slot=t.slot,
              configured_rate_mbps=t.configured_rate_mbps, rate_state=t.rate_state,
              achieved_mbps=t.achieved_mbps, bytes_sent=t.bytes_sent, duration_s=t.duration_s,
              frames_sent=t.frames_sent, request_bytes=t.request_bytes)
    return set_header(msg, stamp, "")


def encoded_keyframe(data: KeyFramePayload | None, image: object | None, slot: int,
                     alpha_bytes: int) -> Encoded | None:
    """A requested frame as the uplink sends it: (frame id, the serialised ``Keyframe`` of
    ``slot``, the bytes it occupies on the link — at least α); None when the device no longer
    holds the frame (``data`` None)."""
    if data is None:
        return None
    payload = serialize_message(keyframe_message(dataclasses.replace(data, slot=slot),
                                                 image=image))
    return data.frame_id, payload, max(alpha_bytes, len(payload))


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


def read_map_update(msg: MapUpdate) -> MapSnapshot:
    """The edge's map as a ``MapUpdate`` carries it, as arrays (what the device tracks
    against; the monitors and the benches read it the same way)."""
    n = len(msg.point_ids)
    counts = np.asarray(msg.keyframe_point_counts, dtype=np.int64)
    keyframe_points = (np.split(np.asarray(msg.keyframe_point_ids, dtype=np.uint64),
                                np.cumsum(counts)[:-1]) if len(counts) else [])
    return MapSnapshot(
        int(msg.map_version), np.asarray(msg.keyframe_ids, dtype=np.uint64),
        np.array([pose_matrix(p) for p in msg.keyframe_poses]).reshape(-1, 4, 4),
        np.asarray(msg.point_ids, dtype=np.uint64),
        np.asarray(msg.point_positions, dtype=np.float64).reshape(n, 3),
        np.asarray(msg.point_descriptors, dtype=np.uint8).reshape(n, ORB_DESCRIPTOR_BYTES),
        np.asarray(msg.point_observations, dtype=np.uint32), keyframe_points,
        np.asarray(msg.track_ids, dtype=np.uint64),
        np.asarray(msg.track_point_ids, dtype=np.uint64), pose_matrix(msg.frame_correction),
        str(msg.header.frame_id))
