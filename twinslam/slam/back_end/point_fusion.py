"""Fusing a restored keyframe's points with the map's: one place, one set of points.

A keyframe the archive gives back brings the points it saw, under their old ids. The map may
have made those points again in the meantime — the device walked the place anew, its uploads
created points from depth where the map held none — and the map would then hold each corner
twice: the device's matches split between the two copies, the covisibility weights between
the old keyframe and the new ones count nothing for what both see, and the bundle adjustment
optimises two points for one. As ORB-SLAM's SearchAndFuse does for a loop, each point that
came back is projected into its keyframe, matched there against the map's other points by
pixel and descriptor, and, where one matches and lies where it does, fused into it
(:meth:`~twinslam.slam.back_end.keyframe_map.KeyFrameMap.fuse`): the newer point stays (the
map has optimised it with today's keyframes), the restored keyframe observes it instead.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from twinslam.slam.back_end.keyframe_map import KeyFrameMap
from twinslam.slam.camera import Camera
from twinslam.slam.projection_matching import match_by_projection, visible_points


@dataclass(frozen=True)
class FusionConfig:
    search_radius_px: float = 8.0
    max_hamming: int = 50
    ratio: float = 0.8
    #: a match fuses only when the two points lie within this many metres of each other (a
    #: look-alike corner elsewhere along the ray is no duplicate)
    max_gap_m: float = 0.10
    depth_range_m: tuple[float, float] = (0.2, 8.0)


def fuse_restored(m: KeyFrameMap, kf_id: int, returned: list[int], camera: Camera,
                  config: FusionConfig | None = None) -> dict[int, int]:
    """Fuse the points ``returned`` with keyframe ``kf_id`` (restored from the archive, seen
    with ``camera``) into the map points that duplicate them; {returned point: the map point
    it became}."""
    cfg = config or FusionConfig()
    kf = m.keyframes[kf_id]
    mine = [p for p in returned if p in m.points and p in kf.measurements
            and math.isfinite(kf.measurements[p][0])]
    others = np.array([p for p in m.points if p not in kf.points], dtype=np.int64)
    if not mine or not others.size:
        return {}
    positions = np.array([m.points[p].position for p in others.tolist()])
    vis, uv = visible_points(positions, np.ones(len(others), dtype=bool), kf.pose,
                             np.asarray(camera.intrinsics, dtype=np.float64), camera.shape,
                             cfg.depth_range_m)
    if not vis.size:
        return {}
    seen_at = np.array([kf.measurements[p][:2] for p in mine], dtype=np.float64)
    f_idx, c_idx = match_by_projection(
        seen_at, np.array([m.points[p].descriptor for p in mine], dtype=np.uint8), uv,
        np.array([m.points[p].descriptor for p in others[vis].tolist()], dtype=np.uint8),
        cfg.search_radius_px, cfg.max_hamming, cfg.ratio, camera.shape)
    fused: dict[int, int] = {}
    for fi, ci in zip(f_idx.tolist(), c_idx.tolist(), strict=True):
        drop, keep = mine[fi], int(others[vis[ci]])
        gap = np.linalg.norm(m.points[drop].position - m.points[keep].position)
        if gap <= cfg.max_gap_m:
            m.fuse(keep, drop)
            fused[drop] = keep
    return fused
