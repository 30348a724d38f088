"""The edge's side of the per-slot protocol as messages (DESIGN.md §1): what it reads from a
``Keyframe`` and what it writes as ``UploadRequest``, ``MapUpdate`` and ``MapStats``. Pure
conversion, no DDS, so the node stays a thin shell and the conversions are tested alone.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from edge_mapper.keyframe_map import KeyframeMap
from msg_schemas import new
from msg_schemas.headers import set_header
from msg_schemas.poses import pose_matrix, pose_msg
from simulator.env import MapAction

DESCRIPTOR_BYTES = 32


@dataclass
class KeyframeData:
    """A received keyframe's content in the shapes the integrator takes."""

    frame_id: int
    slot: int
    pose: np.ndarray               #: 4×4 camera-to-map (the device's estimate)
    intrinsics: np.ndarray         #: 3×3
    keypoints: np.ndarray          #: n×2 float32
    depths: np.ndarray             #: n float32, metres, 0 = none
    descriptors: np.ndarray        #: n×32 uint8
    point_ids: np.ndarray          #: n uint64, 0 = none, top bit = device track id


def read_keyframe(msg: Any) -> KeyframeData:
    """Unpack a (validated) ``Keyframe``."""
    xy = np.asarray(msg.keypoints_xy, dtype=np.float32).reshape(-1, 2)
    n = len(xy)
    depths = np.asarray(msg.keypoint_depths, dtype=np.float32)
    ids = np.asarray(msg.map_point_ids, dtype=np.uint64)
    return KeyframeData(int(msg.frame_id), int(msg.slot), pose_matrix(msg.pose_estimate),
                        np.asarray(msg.k, dtype=np.float64).reshape(3, 3), xy,
                        depths if depths.size == n else np.zeros(n, np.float32),
                        np.asarray(msg.descriptors, dtype=np.uint8).reshape(n, DESCRIPTOR_BYTES),
                        ids if ids.size == n else np.zeros(n, np.uint64))


def upload_request_message(slot: int, policy: str, rate_mbps: float, action: MapAction,
                           stamp: float) -> Any:
    msg = new("twinslam_msgs/msg/UploadRequest", slot=slot, policy=policy, rate_mbps=rate_mbps,
              upload_frame_ids=np.asarray(action.upload, dtype=np.uint64),
              evict_frame_ids=np.asarray(action.evict, dtype=np.uint64))
    return set_header(msg, stamp, "")


def map_update_message(keyframe_map: KeyframeMap, slot: int, version: int, stamp: float,
                       frame_id: str = "map", tracks: dict[int, int] | None = None) -> Any:
    """The whole map for the device: keyframe poses, points with descriptors and how many
    keyframes observe each, and the device tracks that became map points (``tracks``)."""
    tracks = {t: p for t, p in (tracks or {}).items() if p in keyframe_map.points}
    kf_ids = keyframe_map.keyframe_ids()
    pt_ids = sorted(keyframe_map.points)
    pts = [keyframe_map.points[p] for p in pt_ids]
    msg = new("twinslam_msgs/msg/MapUpdate", slot=slot, map_version=version,
              keyframe_ids=np.asarray(kf_ids, dtype=np.uint64),
              keyframe_poses=[pose_msg(keyframe_map.keyframes[k].pose) for k in kf_ids],
              point_ids=np.asarray(pt_ids, dtype=np.uint64),
              point_positions=np.array([p.position for p in pts], dtype=np.float64).reshape(-1),
              point_descriptors=np.array([p.descriptor for p in pts], dtype=np.uint8
                                         ).reshape(-1),
              point_observations=np.array([len(p.observers) for p in pts], dtype=np.uint32),
              keyframe_point_counts=np.array([len(keyframe_map.keyframes[k].points)
                                              for k in kf_ids], dtype=np.uint32),
              keyframe_point_ids=np.array([p for k in kf_ids
                                           for p in sorted(keyframe_map.keyframes[k].points)],
                                          dtype=np.uint64),
              track_ids=np.array(list(tracks), dtype=np.uint64),
              track_point_ids=np.array(list(tracks.values()), dtype=np.uint64))
    return set_header(msg, stamp, frame_id)


@dataclass
class LocalMap:
    """A ``MapUpdate`` as arrays: what the device tracks against."""

    version: int
    keyframe_ids: np.ndarray       #: uint64
    keyframe_poses: np.ndarray     #: k×4×4
    point_ids: np.ndarray          #: uint64
    positions: np.ndarray          #: n×3
    descriptors: np.ndarray        #: n×32 uint8
    observations: np.ndarray       #: n uint32
    keyframe_points: list[np.ndarray] = field(default_factory=list)   #: M_f per keyframe
    track_ids: np.ndarray = field(default_factory=lambda: np.zeros(0, np.uint64))
    track_point_ids: np.ndarray = field(default_factory=lambda: np.zeros(0, np.uint64))


def read_map_update(msg: Any) -> LocalMap:
    n = len(msg.point_ids)
    return LocalMap(int(msg.map_version), np.asarray(msg.keyframe_ids, dtype=np.uint64),
                    np.array([pose_matrix(p) for p in msg.keyframe_poses]).reshape(-1, 4, 4),
                    np.asarray(msg.point_ids, dtype=np.uint64),
                    np.asarray(msg.point_positions, dtype=np.float64).reshape(n, 3),
                    np.asarray(msg.point_descriptors, dtype=np.uint8).reshape(n,
                                                                              DESCRIPTOR_BYTES),
                    np.asarray(msg.point_observations, dtype=np.uint32),
                    np.split(np.asarray(msg.keyframe_point_ids, dtype=np.uint64),
                             np.cumsum(np.asarray(msg.keyframe_point_counts, dtype=np.int64)
                                       )[:-1]) if len(msg.keyframe_point_counts) else [],
                    np.asarray(msg.track_ids, dtype=np.uint64),
                    np.asarray(msg.track_point_ids, dtype=np.uint64))


def map_stats_message(slot: int, policy: str, keyframe_map: KeyframeMap, uncertainty: float,
                      mean_next: float, lost_ratio: float, uploads: int, optimisation_ms: float,
                      processing_ms: float, stamp: float) -> Any:
    """``MapStats``; u = +inf for a disconnected map and υ = NaN with no tracked frame are
    sent as they are (IEEE floats), never replaced by a number that looks valid."""
    msg = new("twinslam_msgs/msg/MapStats", slot=slot, policy=policy,
              map_size=len(keyframe_map.keyframes), map_points=len(keyframe_map.points),
              uncertainty=float(uncertainty),
              mean_next_uncertainty=float(mean_next) if mean_next is not None else math.nan,
              lost_frame_ratio=float(lost_ratio), uploads=uploads,
              optimisation_ms=float(optimisation_ms), slot_processing_ms=float(processing_ms))
    return set_header(msg, stamp, "")
