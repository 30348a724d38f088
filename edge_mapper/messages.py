"""The edge's side of the per-slot protocol as messages (docs/architecture.md §1): what it writes as
``UploadRequest``, ``MapUpdate``, ``MapStats``, ``Relocalisation`` and, serving several devices,
``KeyframeBudget`` (it reads ``Keyframe`` with
:mod:`twinslam.slam.keyframe`). Pure conversion, no DDS, so the node stays a thin shell and
the conversions are tested alone.
"""

from __future__ import annotations

import math

import numpy as np
from twinslam_msgs.msg import (
    FrameSummaries,
    Keyframe,
    MapStats,
    MapUpdate,
    Relocalisation,
    UploadRequest,
)
from twinslam_msgs.msg import KeyframeBudget as KeyframeBudgetMsg

from edge_mapper.keyframe_budget import KeyframeBudget, Presence
from edge_mapper.slot_planner import FrameObservations
from msg_schemas import new
from msg_schemas.headers import set_header, stamp_seconds
from msg_schemas.poses import pose_matrix, pose_msg, pose_msgs
from msg_schemas.validation import ORB_DESCRIPTOR_BYTES
from twinslam.policies.actions import MapAction
from twinslam.slam.back_end.archive_relocalisation import ArchiveLocation
from twinslam.slam.back_end.keyframe_slice import MapView
from twinslam.slam.keyframe import KeyFramePayload
from twinslam.uncertainty.map_uncertainty import SlotUncertainty


def relocalisation_message(slot: int, frame_id: int, found: ArchiveLocation, stamp: float,
                           map_frame: str) -> Relocalisation:
    """The edge's answer to a lost device's relocalisation request."""
    msg = new(Relocalisation, slot=slot, frame_id=frame_id, found=found.found,
              inliers=found.inliers, keyframe_id=max(found.keyframe, 0), reason=found.reason)
    if found.pose is not None:
        msg.pose = pose_msg(found.pose)
    return set_header(msg, stamp, map_frame)


def upload_request_message(slot: int, policy: str, rate_mbps: float, action: MapAction,
                           stamp: float) -> UploadRequest:
    msg = new(UploadRequest, slot=slot, policy=policy, rate_mbps=rate_mbps,
              upload_frame_ids=np.asarray(action.upload, dtype=np.uint64),
              evict_frame_ids=np.asarray(action.evict, dtype=np.uint64))
    return set_header(msg, stamp, "")


def map_update_message(keyframe_map: MapView, slot: int, version: int, stamp: float,
                       frame_id: str = "map", tracks: dict[int, int] | None = None,
                       frame_correction: np.ndarray | None = None) -> MapUpdate:
    """The map the device holds (a map, or the device's slice of its place's): keyframe
    poses, the points they see with descriptors and how many keyframes observe each, the
    device tracks that became map points (``tracks``), and the loops' corrections so far at
    the walk's head (``frame_correction``; None: none)."""
    points = keyframe_map.points      # a slice lists its points at each read: read once
    tracks = {t: p for t, p in (tracks or {}).items() if p in points}
    kf_ids = keyframe_map.keyframe_ids()
    pt_ids, rows = keyframe_map.point_rows()
    # written for every device every slot: each column read straight into its array, each
    # keyframe's observations from the arrays it keeps until they change
    observed = [np.sort(keyframe_map.keyframes[k].observed()[0]) for k in kf_ids]
    msg = new(MapUpdate, slot=slot, map_version=version,
              keyframe_ids=np.asarray(kf_ids, dtype=np.uint64),
              keyframe_poses=pose_msgs([keyframe_map.keyframes[k].pose for k in kf_ids]),
              point_ids=np.asarray(pt_ids, dtype=np.uint64),
              point_positions=keyframe_map.columns.positions[rows].reshape(-1),
              point_descriptors=keyframe_map.columns.descriptors[rows].reshape(-1),
              point_observations=keyframe_map.columns.observed[rows].astype(np.uint32),
              keyframe_point_counts=np.array([len(o) for o in observed], dtype=np.uint32),
              keyframe_point_ids=np.concatenate([np.zeros(0, dtype=np.int64), *observed]
                                                ).astype(np.uint64),
              track_ids=np.array(list(tracks), dtype=np.uint64),
              track_point_ids=np.array(list(tracks.values()), dtype=np.uint64),
              frame_correction=pose_msg(np.eye(4) if frame_correction is None
                                        else frame_correction))
    return set_header(msg, stamp, frame_id)


def map_stats_message(slot: int, policy: str, keyframe_map: MapView, uncertainty: float,
                      upsilon: SlotUncertainty | None, uploads: int, optimisation_ms: float,
                      processing_ms: float, stamp: float, keyframe_budget: int = 0,
                      latency_ms: float = math.nan, archived: int = 0, restored: int = 0,
                      refused: int = 0, frame_id: str = "", loops_closed: int = 0,
                      loop_ms: float = 0.0, loops_refused: int = 0, missing: int = 0
                      ) -> MapStats:
    """``MapStats``, its header in ``frame_id`` (the map frame its keyframe counts describe, so
    a viewer or a bag reader can tell one device's map from another's); u = +inf for a
    disconnected map and υ = NaN (unknown, or no tracked frame) are sent as they are (IEEE
    floats), never replaced by a number that looks valid. υ is reported the three ways
    docs/architecture.md §2 asks: mean with a lost frame scoring 0, the lost share, and the mean
    over the tracked frames."""
    msg = new(MapStats, slot=slot, policy=policy,
              map_size=len(keyframe_map.keyframes), map_points=len(keyframe_map.points),
              archived_keyframes=archived, restored_keyframes=restored,
              refused_keyframes=refused, missing_keyframes=missing,
              keyframe_budget=keyframe_budget,
              uncertainty=float(uncertainty),
              mean_uncertainty=upsilon.objective if upsilon else math.nan,
              tracked_uncertainty=upsilon.tracked_uncertainty if upsilon else math.nan,
              lost_share=upsilon.lost_share if upsilon else 0.0, uploads=uploads,
              optimisation_ms=float(optimisation_ms), slot_processing_ms=float(processing_ms),
              slot_latency_ms=float(latency_ms), loops_closed=int(loops_closed),
              loops_refused=int(loops_refused),
              loop_closing_ms=float(loop_ms))
    return set_header(msg, stamp, frame_id)


def keyframe_budget_message(budget: KeyframeBudget, stamp: float) -> KeyframeBudgetMsg:
    """How ``budget`` stands now, every device it serves in one message."""
    accounts = list(budget.accounts.values())
    msg = new(KeyframeBudgetMsg, allocator=budget.allocator, total=budget.total,
              devices=[a.device for a in accounts],
              targets=np.array([a.target for a in accounts], dtype=np.uint32),
              granted=np.array([a.granted for a in accounts], dtype=np.uint32),
              map_sizes=np.array([a.map_size for a in accounts], dtype=np.uint32),
              committed=np.array([a.committed for a in accounts], dtype=np.uint32),
              active=[a.presence is Presence.ACTIVE for a in accounts])
    return set_header(msg, stamp, "")


def read_frame_summaries(msg: FrameSummaries) -> list[FrameObservations]:
    """A slot's frames as the planner reads them. The id sequences arrive as ``array.array``
    of Python ints: a set is made of one at once (the edge reads every device's hundreds of
    ids a frame, every slot, on the thread that serves them all)."""
    return [FrameObservations(int(f.frame_id), frozenset(f.map_point_ids),
                              frozenset(f.local_track_ids), bool(f.tracked),
                              pose_matrix(f.pose), int(f.map_version))
            for f in msg.frames]


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
