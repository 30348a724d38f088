"""The edge's gate on an uploaded keyframe: a pose no camera could have reached never enters the
map, nor the archive (DESIGN.md §7b).

The device's motion gate (:mod:`twinslam.slam.pose_plausibility`) refuses impossible motions
before they are published; the edge cannot rely on it alone — a device of another make, a
corrupted upload, a pose the device solved against a map that was itself wrong. One keyframe
integrated 10¹² m away makes points there, the bundle adjustment pulls its neighbours towards
them, and the device tracks against that map from then on. A keyframe is refused when

* its pose is not finite;
* it lies out of reach of the map: farther from the keyframe nearest to it in frame ids (the
  map's, the archive's, or the device's first frame, the map's origin) than a camera moving at
  ``max_speed_m_s`` could have gone in the frames between, plus the ``correction_m`` the
  optimisation may have moved things by (frame ids count the device's frames at the camera's
  rate; a device that dropped frames counted fewer, so the reach errs on the short side only
  by what the margin covers);
* it disagrees with its own matched points: of the features the device associated with map
  points the edge still holds, fewer than ``min_consistent_share`` reproject within
  ``reprojection_px`` of where the keyframe saw them (checked only with ``min_matched`` such
  features: a keyframe in new ground matches few).
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field

import numpy as np

from twinslam.slam.back_end.bundle_adjustment import Observation, reprojection_sq
from twinslam.slam.back_end.keyframe_map import KeyFrameMap
from twinslam.slam.keyframe import KeyFramePayload, is_track
from twinslam.slam.pose_plausibility import MotionBounds, non_finite
from twinslam.slot_protocol import table1


@dataclass(frozen=True)
class KeyFrameGateConfig:
    motion: MotionBounds = field(default_factory=MotionBounds)
    frame_rate_hz: float = table1.FRAME_RATE_HZ   #: the device's camera: frame ids to seconds
    #: the consistency check: a matched point agrees within this many pixels (loose: the edge's
    #: bundle adjustment moved the points since the device tracked against them at 3 px)
    reprojection_px: float = 10.0
    min_consistent_share: float = 0.3
    min_matched: int = 15


def implausible_keyframe(keyframe: KeyFramePayload, keyframe_map: KeyFrameMap,
                         anchors: Iterable[tuple[int, np.ndarray]],
                         config: KeyFrameGateConfig = KeyFrameGateConfig(),
                         origin: np.ndarray | None = None) -> str:
    """Why ``keyframe`` must not enter ``keyframe_map``, or "" to integrate it. ``anchors``:
    (frame id, camera-to-map pose) of the keyframes the edge knows beyond the map's own (its
    archive); the device's first frame is always one, at ``origin`` (None: the identity, the
    map's origin — elsewhere once the map was merged into another device's frame)."""
    pose = np.asarray(keyframe.pose, dtype=np.float64)
    if non_finite(pose):
        return "a non-finite pose"
    first = np.eye(4) if origin is None else np.asarray(origin, dtype=np.float64)
    reason = _out_of_reach(keyframe.frame_id, pose, keyframe_map, [(0, first), *anchors],
                           config)
    return reason or _inconsistent(keyframe, pose, keyframe_map, config)


def _out_of_reach(frame_id: int, pose: np.ndarray, keyframe_map: KeyFrameMap,
                  anchors: Iterable[tuple[int, np.ndarray]], config: KeyFrameGateConfig) -> str:
    """Farther from the keyframe nearest in frame ids than a camera gets in the time between
    (the later one of two equally near: the newer pose, after the newer optimisation)."""
    known = [*anchors, *((kf.id, kf.pose) for kf in keyframe_map.keyframes.values())]
    nearest_id, nearest = min(known, key=lambda a: (abs(a[0] - frame_id), -a[0]))
    seconds = abs(frame_id - nearest_id) / config.frame_rate_hz
    reach = config.motion.correction_m + config.motion.max_speed_m_s * seconds
    distance = float(np.linalg.norm(pose[:3, 3] - nearest[:3, 3]))
    if distance > reach:
        return (f"{distance:.3g} m from keyframe {nearest_id}, out of reach ({reach:.2f} m in "
                f"{seconds:.1f} s)")
    return ""


def _inconsistent(keyframe: KeyFramePayload, pose: np.ndarray, keyframe_map: KeyFrameMap,
                  config: KeyFrameGateConfig) -> str:
    """Too few of the map points the device matched the keyframe's features with reproject
    near those features from its pose: the pose and its own evidence disagree."""
    ids = np.asarray(keyframe.point_ids, dtype=np.uint64)
    named = np.flatnonzero((ids != 0) & ~is_track(ids))     # map-point ids, not tracks
    held = keyframe_map.points
    rows = [i for i, pid in zip(named.tolist(), ids[named].tolist(), strict=True)
            if pid in held]
    if len(rows) < config.min_matched:
        return ""
    seen = np.asarray(keyframe.keypoints, dtype=np.float64)
    observations = [Observation(keyframe.frame_id, int(ids[i]), (seen[i, 0], seen[i, 1]),
                                float("nan")) for i in rows]
    points = {ob.point: keyframe_map.points[ob.point].position for ob in observations}
    squared = reprojection_sq({keyframe.frame_id: pose}, points,
                              np.asarray(keyframe.intrinsics, dtype=np.float64), observations)
    agree = squared <= config.reprojection_px ** 2
    share = float(agree.mean())
    if share < config.min_consistent_share:
        return (f"{share:.0%} of its {len(rows)} matched map points reproject within "
                f"{config.reprojection_px:g} px (fewer than {config.min_consistent_share:.0%})")
    return ""
