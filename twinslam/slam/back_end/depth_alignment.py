"""A camera pose from 3D–3D matches: an RGB-D frame's own points (its keypoints lifted by their
depths) against the map points they matched.

PnP solves a pose from where points appear in the image. Facing one wall, a small turn of
the camera and a sideways step move those points alike, and PnP cannot tell them apart: on
the synthetic corridor a loop measured by PnP on 91 inliers was 2° and 5 cm off, enough to
bend 20 m of corridor by half a metre once the pose graph believed it
(docs/results/loop-closing.md). A depth camera measures where each point is, so the turn and
the step no longer look alike. ORB-SLAM closes RGB-D loops the same way — its Sim3 solver
(Horn's closed form) with the scale held at one.

:func:`rigid_fit` is that closed form (Kabsch–Umeyama without scale);
:func:`align_with_depth` starts from a PnP pose, keeps the matches whose lifted point lies
near its map point, fits the pose to them and repeats: PnP has removed the gross outliers,
the depth fixes the ambiguity.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: how far a lifted point may lie from its map point and still count (m), at 1 m of depth and
#: growing with it (a depth camera's error grows with the distance)
NEAR_M = 0.03
PER_METRE = 0.02
#: the rounds' tolerances, times the final one: the start may be a few degrees off (PnP's
#: ambiguity is what the fit is for), so the first round takes what lies within a few times
#: the tolerance and each round after narrows it
WIDENING = (4.0, 2.0, 1.0, 1.0)


@dataclass(frozen=True)
class DepthAlignment:
    """A camera-to-map pose fitted to 3D–3D matches, or why there is none."""

    pose: np.ndarray | None
    inliers: int
    rms_m: float                 #: of the inliers' 3D distances after the fit


def rigid_fit(source: np.ndarray, target: np.ndarray) -> np.ndarray:
    """The rotation and translation (4×4) that carry the points ``source`` (n, 3) closest to
    ``target`` (n, 3) in the least-squares sense; n ≥ 3 points not on one line."""
    src = np.asarray(source, dtype=np.float64).reshape(-1, 3)
    dst = np.asarray(target, dtype=np.float64).reshape(-1, 3)
    if len(src) != len(dst) or len(src) < 3:
        raise ValueError(f"a rigid fit needs as many source as target points, ≥ 3; got "
                         f"{len(src)} and {len(dst)}")
    mu_s, mu_d = src.mean(axis=0), dst.mean(axis=0)
    u, _, vt = np.linalg.svd((dst - mu_d).T @ (src - mu_s))
    flip = np.diag([1.0, 1.0, np.sign(np.linalg.det(u @ vt))])
    rotation = u @ flip @ vt
    fit = np.eye(4)
    fit[:3, :3], fit[:3, 3] = rotation, mu_d - rotation @ mu_s
    return fit


def align_with_depth(start: np.ndarray, camera_points: np.ndarray, world: np.ndarray,
                     min_inliers: int) -> DepthAlignment:
    """The camera-to-map pose that best carries ``camera_points`` (n, 3: matched keypoints
    lifted by their depths, the camera's frame) onto their map points ``world`` (n, 3),
    starting from the pose ``start`` (PnP's): a match counts while its lifted point lies
    within NEAR_M + PER_METRE · depth of its map point (wider in the first rounds,
    WIDENING). None when fewer than ``min_inliers`` (at least 3) matches count."""
    cam = np.asarray(camera_points, dtype=np.float64).reshape(-1, 3)
    ref = np.asarray(world, dtype=np.float64).reshape(-1, 3)
    usable = np.isfinite(cam).all(axis=1) & (cam[:, 2] > 0) & np.isfinite(ref).all(axis=1)
    cam, ref = cam[usable], ref[usable]
    tolerance = NEAR_M + PER_METRE * cam[:, 2] if len(cam) else np.zeros(0)
    pose = np.asarray(start, dtype=np.float64)
    inliers = np.zeros(len(cam), dtype=bool)
    for widening in WIDENING:
        moved = cam @ pose[:3, :3].T + pose[:3, 3]
        inliers = np.linalg.norm(moved - ref, axis=1) <= widening * tolerance
        if inliers.sum() < max(min_inliers, 3):
            return DepthAlignment(None, int(inliers.sum()), float("nan"))
        pose = rigid_fit(cam[inliers], ref[inliers])
    moved = cam @ pose[:3, :3].T + pose[:3, 3]
    distance = np.linalg.norm(moved - ref, axis=1)
    inliers = distance <= tolerance
    if inliers.sum() < max(min_inliers, 3):
        return DepthAlignment(None, int(inliers.sum()), float("nan"))
    return DepthAlignment(pose, int(inliers.sum()),
                          float(np.sqrt(np.mean(distance[inliers] ** 2))))
