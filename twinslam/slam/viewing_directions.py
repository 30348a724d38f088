"""The direction a map point was seen from (ORB-SLAM's map point normal) and the test that a
camera sees it from about there.

ORB's descriptor is not invariant to the viewpoint: a corner seen 60° off the direction its
descriptor was taken from looks like another corner, and a search by projection that tries
it anyway spends its candidate budget on points it cannot match. ORB-SLAM keeps, per map
point, the mean of the unit rays from the keyframes that observed it to the point and
searches a frame for the point only where the frame's ray to it is within 60° of that mean
(``MapPoint::GetNormal``, ``Frame::isInFrustum``'s ``viewCos < 0.5``). Where devices share a
place this matters more than on one device's walk: another person's keyframes saw a corridor
from their own height and gaze, and a copy of their map holds points seen from directions
this device's camera never takes.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from twinslam.slam.sorted_ids import find_sorted


def mean_viewing_directions(point_ids: np.ndarray, positions: np.ndarray,
                            keyframe_poses: np.ndarray | Sequence[np.ndarray],
                            keyframe_points: Sequence[np.ndarray]) -> np.ndarray:
    """Per point (``point_ids``, ``positions`` n×3), the unit mean of the rays from the
    camera centres of the keyframes that observed it (``keyframe_poses`` camera-to-world,
    ``keyframe_points`` the ids each observed) to the point; NaN rows for a point no keyframe
    observed (or seen from exactly opposite sides: no direction)."""
    ids = np.asarray(point_ids, dtype=np.uint64)
    positions = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
    out = np.full((len(ids), 3), np.nan)
    sizes = [len(p) for p in keyframe_points]
    if not len(ids) or not sum(sizes):
        return out
    seen = np.concatenate([np.asarray(p, dtype=np.uint64) for p in keyframe_points])
    centres = np.asarray(keyframe_poses, dtype=np.float64)[:, :3, 3]
    by = np.repeat(np.arange(len(sizes)), sizes)
    order = np.argsort(ids, kind="stable")
    at, held = find_sorted(ids[order], seen)
    rows = order[at[held]]
    rays = positions[rows] - centres[by[held]]
    length = np.linalg.norm(rays, axis=1)
    ok = length > 0
    unit = rays[ok] / length[ok, None]
    total = np.column_stack([np.bincount(rows[ok], weights=unit[:, k], minlength=len(ids))
                             for k in range(3)])
    norm = np.linalg.norm(total, axis=1)
    some = norm > 1e-9
    out[some] = total[some] / norm[some, None]
    return out


def rays_from(centre: np.ndarray, positions: np.ndarray) -> np.ndarray:
    """Unit rays (n×3) from a camera ``centre`` to ``positions``: a new point's viewing
    direction, seen from the keyframe that made it (NaN for a point at the centre)."""
    rays = np.asarray(positions, dtype=np.float64).reshape(-1, 3) - np.asarray(centre)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.asarray(rays / np.linalg.norm(rays, axis=1)[:, None])


def seen_from_afar(views: np.ndarray, positions: np.ndarray, centre: np.ndarray,
                   max_angle_deg: float) -> np.ndarray:
    """Which points a camera at ``centre`` sees from more than ``max_angle_deg`` off their
    viewing direction (``views``, unit rows; a NaN row — no direction known — never is)."""
    cos = np.einsum("ij,ij->i", rays_from(centre, positions), np.asarray(views))
    with np.errstate(invalid="ignore"):
        return np.asarray(cos < np.cos(np.radians(max_angle_deg)))
