"""Local bundle adjustment of the edge's keyframe map with GTSAM.

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
window): each holds a prior of σ = 1e-6 rather than a hard ``NonlinearEquality``, whose
constrained noise model forces QR elimination and was measured 10× slower on a 24-keyframe,
2 300-point local map. Gauss–Newton (iteratively reweighted by the Huber kernel) solves it: on
that map 3 iterations reach within 0.3 % of Levenberg–Marquardt's 5-iteration error in 100 ms
instead of 360 ms. Observations whose reprojection error stays above the threshold are
reported as outliers.
"""

from __future__ import annotations

import math
import time
from collections.abc import Mapping
from dataclasses import dataclass, field

import gtsam
import numpy as np
from gtsam.symbol_shorthand import L, X

#: χ²(2 dof, 95 %): ORB-SLAM's threshold for a monocular reprojection error, in σ²
CHI2_MONO = 5.991
FIXED_SIGMA = 1e-6                  #: prior σ (rad, m) that holds a fixed keyframe


@dataclass(frozen=True)
class _Calibration:
    """One camera's calibrations as GTSAM's factors take them."""

    fx: float
    mono: gtsam.Cal3_S2
    stereo: gtsam.Cal3_S2Stereo

    @classmethod
    def of(cls, k: np.ndarray, baseline_m: float) -> _Calibration:
        fx, fy, cx, cy = k[0, 0], k[1, 1], k[0, 2], k[1, 2]
        return cls(float(fx), gtsam.Cal3_S2(fx, fy, 0.0, cx, cy),
                   gtsam.Cal3_S2Stereo(fx, fy, 0.0, cx, cy, baseline_m))


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
    #: why its caller did not apply it ("": applied), e.g. the edge's check of a diverged solve
    refused: str = ""


def bundle_adjust(poses: dict[int, np.ndarray], points: dict[int, np.ndarray],
                  observations: list[Observation], intrinsics: np.ndarray,
                  fixed: set[int], pixel_sigma: float = 1.0, baseline_m: float = 0.08,
                  max_iterations: int = 3, cameras: Mapping[int, np.ndarray] | None = None
                  ) -> BundleAdjustmentResult:
    """Optimise keyframe poses and point positions over the observations; ``fixed`` keyframes
    do not move (give at least one). Unknown ids in observations are an error. Every
    keyframe was taken by the camera of ``intrinsics`` but those ``cameras`` names (keyframe
    id → 3×3: another device's keyframes in a shared place, whose pixels mean other rays)."""
    start = time.perf_counter()
    if not fixed or not fixed <= set(poses):
        raise ValueError(f"fixed keyframes {sorted(fixed)} must be a non-empty subset of the "
                         "poses (they remove the gauge freedom)")
    k = np.asarray(intrinsics, dtype=np.float64)
    own = _Calibration.of(k, baseline_m)
    calibrations = {kf: _Calibration.of(np.asarray(c, dtype=np.float64), baseline_m)
                    for kf, c in (cameras or {}).items()}
    huber = gtsam.noiseModel.mEstimator.Huber.Create(math.sqrt(CHI2_MONO))
    mono_noise = gtsam.noiseModel.Robust.Create(
        huber, gtsam.noiseModel.Isotropic.Sigma(2, pixel_sigma))
    stereo_noise = gtsam.noiseModel.Robust.Create(
        huber, gtsam.noiseModel.Isotropic.Sigma(3, pixel_sigma))

    hold = gtsam.noiseModel.Isotropic.Sigma(6, FIXED_SIGMA)
    # a point seen once without depth is a ray, not a position: it stays where it is
    views: dict[int, int] = {}
    for ob in observations:
        has_depth = math.isfinite(ob.depth) and ob.depth > 0
        views[ob.point] = views.get(ob.point, 0) + (2 if has_depth else 1)
    determined = {p for p, n in views.items() if n >= 2}

    graph = gtsam.NonlinearFactorGraph()
    initial = gtsam.Values()
    for kf, pose in poses.items():
        initial.insert(X(kf), gtsam.Pose3(np.asarray(pose, dtype=np.float64)))
        if kf in fixed:
            graph.add(gtsam.PriorFactorPose3(X(kf), gtsam.Pose3(pose), hold))
    for pid, xyz in points.items():
        if pid in determined:
            initial.insert(L(pid), gtsam.Point3(*np.asarray(xyz, dtype=np.float64)))
    for ob in observations:
        if ob.keyframe not in poses or ob.point not in points:
            raise ValueError(f"observation of point {ob.point} by keyframe {ob.keyframe}: "
                             "unknown keyframe or point")
        if ob.point not in determined:
            continue
        u, v = ob.uv
        cal = calibrations.get(ob.keyframe, own)
        if math.isfinite(ob.depth) and ob.depth > 0:
            measured = gtsam.StereoPoint2(u, u - cal.fx * baseline_m / ob.depth, v)
            graph.add(gtsam.GenericStereoFactor3D(measured, stereo_noise, X(ob.keyframe),
                                                  L(ob.point), cal.stereo))
        else:
            graph.add(gtsam.GenericProjectionFactorCal3_S2(
                gtsam.Point2(u, v), mono_noise, X(ob.keyframe), L(ob.point), cal.mono))

    params = gtsam.GaussNewtonParams()
    params.setMaxIterations(max_iterations)
    optimizer = gtsam.GaussNewtonOptimizer(graph, initial, params)
    initial_error = graph.error(initial)
    try:
        result = optimizer.optimize()
    except RuntimeError:        # an ill-posed corner (e.g. two nearly parallel rays): damped
        lm = gtsam.LevenbergMarquardtParams()
        lm.setMaxIterations(max_iterations)
        result = gtsam.LevenbergMarquardtOptimizer(graph, initial, lm).optimize()
    out_poses = {kf: np.asarray(poses[kf], dtype=np.float64) if kf in fixed
                 else result.atPose3(X(kf)).matrix() for kf in poses}
    out_points = {pid: np.asarray(result.atPoint3(L(pid))) if pid in determined
                  else np.asarray(xyz, dtype=np.float64) for pid, xyz in points.items()}
    used = [ob for ob in observations if ob.point in determined]
    errors = reprojection_sq(out_poses, out_points, k, used, cameras)
    outliers = [ob for ob, e in zip(used, errors, strict=True)
                if e > CHI2_MONO * pixel_sigma ** 2]
    return BundleAdjustmentResult(out_poses, out_points, initial_error, graph.error(result),
                                  optimizer.iterations(), outliers,
                                  (time.perf_counter() - start) * 1000)


def reprojection_sq(poses: dict[int, np.ndarray], points: dict[int, np.ndarray],
                    k: np.ndarray, observations: list[Observation],
                    cameras: Mapping[int, np.ndarray] | None = None) -> np.ndarray:
    """Squared pixel distance between each observation's ``uv`` and its point's projection
    (inf behind the camera), all observations at once: the outlier test after an adjustment,
    and how well a set of poses (the ground truth's, say) explains the images. Each
    keyframe's camera is ``k`` but those ``cameras`` names."""
    if not observations:
        return np.zeros(0)
    world_to_cam = {kf: np.linalg.inv(p) for kf, p in poses.items()}
    cw = np.array([world_to_cam[ob.keyframe] for ob in observations])
    xyz = np.array([points[ob.point] for ob in observations])
    uv = np.array([ob.uv for ob in observations])
    cam = np.einsum("nij,nj->ni", cw[:, :3, :3], xyz) + cw[:, :3, 3]
    z = cam[:, 2]
    cameras = cameras or {}
    ks = np.array([cameras.get(ob.keyframe, k) for ob in observations]) if cameras else \
        np.broadcast_to(np.asarray(k, dtype=np.float64), (len(observations), 3, 3))
    with np.errstate(divide="ignore", invalid="ignore"):
        proj = cam[:, :2] / z[:, None] * ks[:, [0, 1], [0, 1]] + ks[:, [0, 1], [2, 2]]
    err = ((proj - uv) ** 2).sum(axis=1)
    return np.where(z > 0, err, np.inf)
