"""Camera pose from 2D–3D matches, started at the motion model's prediction (ORB-SLAM's
PoseOptimization).

ORB-SLAM does not run RANSAC on frames it tracks with its motion model: the prediction is
already close, so it refines it by Gauss–Newton on the reprojection error with a Huber kernel,
in four rounds that each re-classify matches as inliers (reprojection error under the
threshold) or outliers, the last round without the kernel on the inliers only. RANSAC is the
fallback when that fails. Here that costs ~0.1 ms against ~2 ms for RANSAC + LM.

The pose is world-to-camera (R, t); an update δ = (ω, v) acts on camera coordinates,
X_c ← exp(ω)·X_c + v, so ∂X_c/∂δ = [−[X_c]×  I] and each step is a 6×6 solve.

An RGB-D frame measures each feature's depth too. ORB-SLAM2 uses it as a stereo camera's
right-image coordinate, u_R = u − bf/z with bf a virtual baseline times fx: a third residual
for each match with a depth reading (``inverse_depths`` > 0), whose inlier test widens from the
χ² bound of two degrees of freedom to three (5.991 → 7.815), as ORB-SLAM2's. A match without
depth keeps the two pixel residuals.
"""

from __future__ import annotations

import numpy as np

from twinslam.kernel_cache import njit

ROUNDS = 4              #: inlier/outlier re-classifications (ORB-SLAM: 4)
ITERATIONS = 10         #: Gauss–Newton steps per round (ORB-SLAM: 10)
#: a match with depth has three residuals: its inlier bound is the χ² bound of three degrees
#: of freedom over two's, at 95 % (ORB-SLAM2: 7.815 and 5.991)
THREE_OVER_TWO = 7.815 / 5.991


@njit(cache=True)
def _rodrigues(w: np.ndarray) -> np.ndarray:
    theta = np.sqrt(w[0] * w[0] + w[1] * w[1] + w[2] * w[2])
    r = np.eye(3)
    if theta < 1e-12:
        return r
    kx, ky, kz = w[0] / theta, w[1] / theta, w[2] / theta
    s, c = np.sin(theta), np.cos(theta)
    kk = np.array([[0.0, -kz, ky], [kz, 0.0, -kx], [-ky, kx, 0.0]])
    return np.asarray(r + s * kk + (1.0 - c) * (kk @ kk))


@njit(cache=True)
def _solve6(h: np.ndarray, g: np.ndarray) -> np.ndarray:
    """x with h·x = g for a symmetric positive definite 6×6 h (Cholesky)."""
    n = 6
    lo = np.zeros((n, n))
    for j in range(n):
        s = h[j, j]
        for p in range(j):
            s -= lo[j, p] * lo[j, p]
        if s <= 0.0:
            return np.full(n, np.nan)
        lo[j, j] = np.sqrt(s)
        for i in range(j + 1, n):
            s = h[i, j]
            for p in range(j):
                s -= lo[i, p] * lo[j, p]
            lo[i, j] = s / lo[j, j]
    y = np.zeros(n)
    for i in range(n):
        s = g[i]
        for p in range(i):
            s -= lo[i, p] * y[p]
        y[i] = s / lo[i, i]
    x = np.zeros(n)
    for i in range(n - 1, -1, -1):
        s = y[i]
        for p in range(i + 1, n):
            s -= lo[p, i] * x[p]
        x[i] = s / lo[i, i]
    return x


@njit(cache=True)
def _optimize(world: np.ndarray, pixels: np.ndarray, inverse_depths: np.ndarray,
              k: np.ndarray, bf: float, rot: np.ndarray, trans: np.ndarray, threshold: float,
              rounds: int, iterations: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    n = world.shape[0]
    fx, fy, cx, cy = k[0, 0], k[1, 1], k[0, 2], k[1, 2]
    thr2 = threshold * threshold
    thr2_depth = thr2 * THREE_OVER_TWO
    inlier = np.ones(n, dtype=np.bool_)
    r, t = rot.copy(), trans.copy()
    for rnd in range(rounds):
        robust = rnd < rounds - 1
        for _ in range(iterations):
            h = np.zeros((6, 6))
            g = np.zeros(6)
            jac = np.zeros((3, 6))
            for i in range(n):
                if not inlier[i]:
                    continue
                x = r[0, 0] * world[i, 0] + r[0, 1] * world[i, 1] + r[0, 2] * world[i, 2] + t[0]
                y = r[1, 0] * world[i, 0] + r[1, 1] * world[i, 1] + r[1, 2] * world[i, 2] + t[1]
                z = r[2, 0] * world[i, 0] + r[2, 1] * world[i, 1] + r[2, 2] * world[i, 2] + t[2]
                if z <= 1e-6:
                    continue
                iz = 1.0 / z
                ex = fx * x * iz + cx - pixels[i, 0]
                ey = fy * y * iz + cy - pixels[i, 1]
                e2 = ex * ex + ey * ey
                has_depth = inverse_depths[i] > 0.0
                # the right image's coordinate: u − bf/z, against the measured u − bf/z_meas
                er = ex - bf * (iz - inverse_depths[i]) if has_depth else 0.0
                e2 += er * er
                bound = thr2_depth if has_depth else thr2
                wgt = 1.0
                if robust and e2 > bound:          # Huber: linear beyond the threshold
                    wgt = np.sqrt(bound / e2) if has_depth else threshold / np.sqrt(e2)
                # d(pixel)/d(X_c) times d(X_c)/d(ω, v) = [-[X_c]x  I]
                a0, a2 = fx * iz, -fx * x * iz * iz
                b1, b2 = fy * iz, -fy * y * iz * iz
                jac[0, 0], jac[0, 1], jac[0, 2] = a2 * y, a0 * z - a2 * x, -a0 * y
                jac[0, 3], jac[0, 4], jac[0, 5] = a0, 0.0, a2
                jac[1, 0], jac[1, 1], jac[1, 2] = b2 * y - b1 * z, -b2 * x, b1 * x
                jac[1, 3], jac[1, 4], jac[1, 5] = 0.0, b1, b2
                if has_depth:                      # u_R's row: u's, its z column + bf/z²
                    c2 = a2 + bf * iz * iz
                    jac[2, 0], jac[2, 1], jac[2, 2] = c2 * y, a0 * z - c2 * x, -a0 * y
                    jac[2, 3], jac[2, 4], jac[2, 5] = a0, 0.0, c2
                for p in range(6):
                    g[p] -= wgt * (jac[0, p] * ex + jac[1, p] * ey
                                   + (jac[2, p] * er if has_depth else 0.0))
                    for q in range(p, 6):
                        h[p, q] += wgt * (jac[0, p] * jac[0, q] + jac[1, p] * jac[1, q]
                                          + (jac[2, p] * jac[2, q] if has_depth else 0.0))
            for p in range(6):
                for q in range(p):
                    h[p, q] = h[q, p]
                h[p, p] += 1e-9
            step = _solve6(h, g)
            if np.isnan(step[0]):
                break
            d_rot = _rodrigues(step[:3])
            r = d_rot @ r
            t = d_rot @ t + step[3:]
            if np.sum(step * step) < 1e-14:
                break
        for i in range(n):                         # re-classify every match
            x = r[0, 0] * world[i, 0] + r[0, 1] * world[i, 1] + r[0, 2] * world[i, 2] + t[0]
            y = r[1, 0] * world[i, 0] + r[1, 1] * world[i, 1] + r[1, 2] * world[i, 2] + t[1]
            z = r[2, 0] * world[i, 0] + r[2, 1] * world[i, 1] + r[2, 2] * world[i, 2] + t[2]
            if z <= 1e-6:
                inlier[i] = False
                continue
            ex = fx * x / z + cx - pixels[i, 0]
            ey = fy * y / z + cy - pixels[i, 1]
            if inverse_depths[i] > 0.0:
                er = ex - bf * (1.0 / z - inverse_depths[i])
                inlier[i] = ex * ex + ey * ey + er * er < thr2_depth
            else:
                inlier[i] = ex * ex + ey * ey < thr2
    return r, t, inlier


def optimize_pose(world: np.ndarray, pixels: np.ndarray, intrinsics: np.ndarray,
                  world_to_camera: np.ndarray, threshold_px: float,
                  depths: np.ndarray | None = None, baseline_m: float = 0.0
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Refined 4×4 world-to-camera pose and the inlier mask (reprojection error below
    ``threshold_px`` at the refined pose), starting from ``world_to_camera``. ``depths``
    (metres, 0: none) with a virtual ``baseline_m`` above 0 add each match's depth as a
    stereo camera's right-image coordinate (see the module's text)."""
    n = len(world)
    inverse = np.zeros(n)
    if depths is not None and baseline_m > 0.0:
        z = np.asarray(depths, dtype=np.float64).reshape(n)
        inverse = np.where(z > 0.0, 1.0 / np.where(z > 0.0, z, 1.0), 0.0)
    k = np.ascontiguousarray(intrinsics, dtype=np.float64)
    r, t, inlier = _optimize(np.ascontiguousarray(world, dtype=np.float64),
                             np.ascontiguousarray(pixels, dtype=np.float64), inverse, k,
                             float(baseline_m) * float(k[0, 0]),
                             np.ascontiguousarray(world_to_camera[:3, :3], dtype=np.float64),
                             np.ascontiguousarray(world_to_camera[:3, 3], dtype=np.float64),
                             float(threshold_px), ROUNDS, ITERATIONS)
    pose = np.eye(4)
    pose[:3, :3], pose[:3, 3] = r, t
    return pose, inlier
