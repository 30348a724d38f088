"""Local bundle adjustment of the edge's keyframe map with GTSAM (issue #5's back end).

The factor graph reads like ORB-SLAM's RGB-D local BA: a keyframe pose x_i (camera-to-world,
``gtsam.Pose3``) and a map point l_j (``gtsam.Point3``) are linked by one factor per
observation,

* a **stereo projection factor** when the keyframe measured the point's depth z — the RGB-D
  frame acts as a rectified stereo pair with a virtual baseline b, right-image coordinate
  u_R = u − f_x·b / z (ORB-SLAM's trick), which fixes the metric scale;
* a **monocular projection factor** otherwise;

each with a Huber kernel at √5.991 σ (the 95 % χ² bound of a 2-dof reprojection error,
ORB-SLAM's outlier test) so that a wrong association pulls with bounded force. The keyframes
in ``fixed`` do not move (the gauge freedom; ORB-SLAM fixes the keyframes outside its local
window). Levenberg–Marquardt solves it; observations whose reprojection error stays above the
threshold are reported as outliers.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import gtsam
import numpy as np
from gtsam.symbol_shorthand import L, X

#: χ²(2 dof, 95 %): ORB-SLAM's threshold for a monocular reprojection error, in σ²
CHI2_MONO = 5.991


@dataclass(frozen=True)
class Observation:
    keyframe: int                   #: keyframe id
    point: int                      #: map point id
    uv: tuple[float, float]         #: pixel where the keyframe saw the point
    depth: float = math.nan         #: metres, NaN when the frame has none there


@dataclass
class BundleAdjustmentResult:
    poses: dict[int, np.ndarray]    #: keyframe id → 4×4 camera-to-world after optimisation
    points: dict[int, np.ndarray]   #: point id → xyz
    initial_error: float            #: the graph's total (robust) error before...
    final_error: float              #: ...and after
    iterations: int
    outliers: list[Observation] = field(default_factory=list)
    milliseconds: float = 0.0


def bundle_adjust(poses: dict[int, np.ndarray], points: dict[int, np.ndarray],
                  observations: list[Observation], intrinsics: np.ndarray,
                  fixed: set[int], pixel_sigma: float = 1.0, baseline_m: float = 0.08,
                  max_iterations: int = 20) -> BundleAdjustmentResult:
    """Optimise keyframe poses and point positions over the observations; ``fixed`` keyframes
    do not move (give at least one). Unknown ids in observations are an error."""
    start = time.perf_counter()
    if not fixed or not fixed <= set(poses):
        raise ValueError(f"fixed keyframes {sorted(fixed)} must be a non-empty subset of the "
                         "poses (they remove the gauge freedom)")
    k = np.asarray(intrinsics, dtype=np.float64)
    fx, fy, cx, cy = k[0, 0], k[1, 1], k[0, 2], k[1, 2]
    mono_cal = gtsam.Cal3_S2(fx, fy, 0.0, cx, cy)
    stereo_cal = gtsam.Cal3_S2Stereo(fx, fy, 0.0, cx, cy, baseline_m)
    huber = gtsam.noiseModel.mEstimator.Huber.Create(math.sqrt(CHI2_MONO))
    mono_noise = gtsam.noiseModel.Robust.Create(
        huber, gtsam.noiseModel.Isotropic.Sigma(2, pixel_sigma))
    stereo_noise = gtsam.noiseModel.Robust.Create(
        huber, gtsam.noiseModel.Isotropic.Sigma(3, pixel_sigma))

    graph = gtsam.NonlinearFactorGraph()
    initial = gtsam.Values()
    for kf, pose in poses.items():
        initial.insert(X(kf), gtsam.Pose3(np.asarray(pose, dtype=np.float64)))
        if kf in fixed:
            graph.add(gtsam.NonlinearEqualityPose3(X(kf), gtsam.Pose3(pose)))
    for pid, xyz in points.items():
        initial.insert(L(pid), gtsam.Point3(*np.asarray(xyz, dtype=np.float64)))
    for ob in observations:
        if ob.keyframe not in poses or ob.point not in points:
            raise ValueError(f"observation of point {ob.point} by keyframe {ob.keyframe}: "
                             "unknown keyframe or point")
        u, v = ob.uv
        if math.isfinite(ob.depth) and ob.depth > 0:
            measured = gtsam.StereoPoint2(u, u - fx * baseline_m / ob.depth, v)
            graph.add(gtsam.GenericStereoFactor3D(measured, stereo_noise, X(ob.keyframe),
                                                  L(ob.point), stereo_cal))
        else:
            graph.add(gtsam.GenericProjectionFactorCal3_S2(
                gtsam.Point2(u, v), mono_noise, X(ob.keyframe), L(ob.point), mono_cal))

    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(max_iterations)
    optimizer = gtsam.LevenbergMarquardtOptimizer(graph, initial, params)
    initial_error = graph.error(initial)
    result = optimizer.optimize()
    out_poses = {kf: result.atPose3(X(kf)).matrix() for kf in poses}
    out_points = {pid: np.asarray(result.atPoint3(L(pid))) for pid in points}
    world_to_cam = {kf: np.linalg.inv(p) for kf, p in out_poses.items()}
    outliers = [ob for ob in observations
                if _reprojection_sq(world_to_cam[ob.keyframe], out_points[ob.point], k, ob.uv)
                > CHI2_MONO * pixel_sigma ** 2]
    return BundleAdjustmentResult(out_poses, out_points, initial_error, graph.error(result),
                                  optimizer.iterations(), outliers,
                                  (time.perf_counter() - start) * 1000)


def _reprojection_sq(world_to_camera: np.ndarray, xyz: np.ndarray, k: np.ndarray,
                     uv: tuple[float, float]) -> float:
    """Squared pixel distance between ``uv`` and the point's projection (inf behind)."""
    cw = world_to_camera
    cam = cw[:3, :3] @ xyz + cw[:3, 3]
    if cam[2] <= 0:
        return math.inf
    u = k[0, 0] * cam[0] / cam[2] + k[0, 2]
    v = k[1, 1] * cam[1] / cam[2] + k[1, 2]
    return (u - uv[0]) ** 2 + (v - uv[1]) ** 2
