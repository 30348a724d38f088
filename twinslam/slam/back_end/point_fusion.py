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
from collections.abc import Collection
from dataclasses import dataclass

import numpy as np

from twinslam.slam.back_end.keyframe_map import KeyFrameMap
from twinslam.slam.camera import Camera
from twinslam.slam.projection_matching import match_by_projection, visible_points


@dataclass(frozen=True)
class MapPoints:
    """Some of a map's points read out at once — ids, positions, descriptors, in one order —
    for the searches that look among them: welding a batch of another device's keyframes
    to a map compares each with all the map's points, which do not change in between."""

    ids: np.ndarray                #: (n,) int64
    positions: np.ndarray          #: (n, 3)
    descriptors: np.ndarray        #: (n, 32) uint8

    @classmethod
    def every(cls, m: KeyFrameMap, but: Collection[int] = ()) -> MapPoints:
        """Every point of map ``m`` as it is now (copies, in the map's order), but those
        ``but`` names."""
        ids, rows = m.columns.ids_and_rows()
        if but:
            keep = ~np.isin(ids, np.fromiter(but, dtype=np.int64, count=len(but)))
            ids, rows = ids[keep], rows[keep]
        return cls(ids, m.columns.positions[rows], m.columns.descriptors[rows])


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
    kf = m.keyframes[kf_id]
    mine = [p for p in returned if p in m.points and p in kf.measurements
            and math.isfinite(kf.measurements[p][0])]
    pairs = duplicates_in_view(
        kf.pose, np.array([kf.measurements[p][:2] for p in mine], dtype=np.float64),
        m.descriptors_of(mine), m.positions_of(mine), MapPoints.every(m, but=kf.points),
        camera, config)
    fused = {mine[row]: keep for row, keep in pairs}
    m.fuse_many([(keep, drop) for drop, keep in fused.items()])
    return fused


def duplicates_in_view(pose: np.ndarray, seen_at: np.ndarray, descriptors: np.ndarray,
                       positions: np.ndarray, candidates: MapPoints, camera: Camera,
                       config: FusionConfig | None = None) -> list[tuple[int, int]]:
    """Which of a keyframe's points (camera-to-map ``pose``; each seen at pixel ``seen_at``,
    with its ``descriptors`` and map ``positions``) are copies of a map's points
    ``candidates``: the candidate projects beside where the keyframe saw the point, looks
    alike (Lowe's ratio) and lies within ``max_gap_m`` of it; (row, the candidate's id)
    pairs, each candidate at most once. What a restored keyframe's points are fused by, and
    another device's keyframe welded to a map it joins
    (:func:`~twinslam.slam.back_end.map_merging.welded`)."""
    cfg = config or FusionConfig()
    if not len(seen_at) or not len(candidates.ids):
        return []
    where = candidates.positions
    vis, uv = visible_points(where, np.ones(len(where), dtype=bool), pose,
                             np.asarray(camera.intrinsics, dtype=np.float64), camera.shape,
                             cfg.depth_range_m)
    if not vis.size:
        return []
    f_idx, c_idx = match_by_projection(seen_at, descriptors, uv, candidates.descriptors[vis],
                                       cfg.search_radius_px, cfg.max_hamming, cfg.ratio,
                                       camera.shape)
    rows = vis[c_idx]
    near = np.linalg.norm(np.asarray(positions, dtype=np.float64)[f_idx] - where[rows],
                          axis=1) <= cfg.max_gap_m
    return list(zip(f_idx[near].tolist(), candidates.ids[rows[near]].tolist(), strict=True))
