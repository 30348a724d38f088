"""Map points that later keyframes should see and never find, removed (ORB-SLAM's
``LocalMapping::MapPointCulling``, its found-ratio rule, counted over keyframes).

A point made from one feature's depth may be a reflection, a depth edge's mixed reading or a
second copy of a corner the map already had (the feature was matched to neither): the
keyframes that come after look at where it is and never match it again, while the device,
which tracks on the map update's points, matches its own features against it and finds its
pose disagree with them (an outlier of its pose solve). Each point counts the keyframes whose
view held it (``MapPoint.visible``) and those of them that observed it (``MapPoint.found``).
Once ``min_visible`` views held it, a point found in fewer than ``min_found_ratio`` of them
leaves the map, its observations with it.

A view "holds" a point (ORB-SLAM's ``isInFrustum``) when it projects into the image within the
depth range and the keyframe looks at it within ``max_view_angle_deg`` of the mean direction
its observers saw it from: a wall's point seen from behind the wall is not expected to be
found. ORB-SLAM counts views over every tracked frame; here only keyframes count (the edge sees
no other frames), so ``min_visible`` stands for the frames ORB-SLAM waits for.
"""

from __future__ import annotations

from collections.abc import Collection
from dataclasses import dataclass
from itertools import chain, repeat

import numpy as np

from twinslam.slam.back_end.keyframe_map import KeyFrameMap


@dataclass(frozen=True)
class PointCullingConfig:
    #: a point found by fewer than this share of the keyframes that should see it is removed
    #: (ORB-SLAM: 0.25)
    min_found_ratio: float = 0.25
    #: keyframes whose view held a point (its creator counted) before the ratio is judged: a
    #: guard for ratios above ORB-SLAM's (with 0.25 a point found once is first removed at
    #: its fifth view anyway)
    min_visible: int = 4
    #: a keyframe looking at a point farther than this from its observers' mean direction
    #: does not count as holding it in view (ORB-SLAM: 60°)
    max_view_angle_deg: float = 60.0


def facing(keyframe_map: KeyFrameMap, point_ids: np.ndarray, camera_to_world: np.ndarray,
           max_angle_deg: float) -> np.ndarray:
    """The mask of ``point_ids`` a camera at ``camera_to_world`` looks at within
    ``max_angle_deg`` of the mean direction their observers saw them from (a point no
    keyframe observes has no such direction and counts as faced). Every (point, observer)
    ray at once: integration asks this of the thousands of points a keyframe's view holds."""
    ids = np.asarray(point_ids, dtype=np.int64)
    if ids.size == 0:
        return np.zeros(0, dtype=bool)
    points = keyframe_map.points
    positions = keyframe_map.positions_of(ids)
    kept = list(keyframe_map.keyframes.values())
    centres = np.array([kf.pose[:3, 3] for kf in kept]).reshape(-1, 3)
    index = {kf.id: i for i, kf in enumerate(kept)}
    observers = [points[p].observers for p in ids.tolist()]
    counts = np.fromiter(map(len, observers), dtype=np.int64, count=len(observers))
    by = np.fromiter(map(index.get, chain.from_iterable(observers), repeat(-1)),
                     dtype=np.int64, count=int(counts.sum()))
    owner = np.repeat(np.arange(len(ids)), counts)
    held = by >= 0                   # an observer the map no longer keeps gives no ray
    owner, by = owner[held], by[held]
    rays = positions[owner] - centres[by]
    rays /= np.maximum(np.linalg.norm(rays, axis=1, keepdims=True), 1e-12)
    n_rays = np.bincount(owner, minlength=len(ids))
    mean_dir = np.column_stack([np.bincount(owner, weights=rays[:, c], minlength=len(ids))
                                for c in range(3)])
    has = n_rays > 0
    mean_dir[has] = mean_dir[has] / n_rays[has, None]
    ray = positions - camera_to_world[:3, 3]
    ray_norm = np.linalg.norm(ray, axis=1)
    dir_norm = np.linalg.norm(mean_dir, axis=1)
    unknown = dir_norm < 1e-9
    cos = np.einsum("ij,ij->i", ray, mean_dir) / np.maximum(ray_norm * dir_norm, 1e-12)
    return np.asarray(unknown | (cos >= np.cos(np.radians(max_angle_deg))))


def count_and_cull(keyframe_map: KeyFrameMap, found: Collection[int],
                   in_view: Collection[int], config: PointCullingConfig) -> list[int]:
    """One keyframe's views counted — ``found``: the map's points it observed (those it made
    itself excluded: they start at one view, one find), ``in_view``: the others its view
    held — and the points of ``in_view`` whose found ratio fell below the bound removed;
    their ids. The counts live in the map's point columns: a keyframe's thousands of points
    are counted at once."""
    columns = keyframe_map.columns
    seen = set(found)
    rows = columns.rows_of(seen)
    columns.visible[rows] += 1
    columns.found[rows] += 1
    others = np.array(sorted(set(in_view) - seen), dtype=np.int64)
    found_rows = columns.rows_or_none(others)
    kept = found_rows >= 0                    # a point that already left is not counted
    held, rows = others[kept], found_rows[kept]
    columns.visible[rows] += 1
    visible, found_in = columns.visible[rows], columns.found[rows]
    gone = (visible >= config.min_visible) & (found_in < config.min_found_ratio * visible)
    culled: list[int] = held[gone].tolist()
    for p in culled:
        keyframe_map.remove_point(p)
    return culled
