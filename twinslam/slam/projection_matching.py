"""Descriptor matching restricted to where a map point should appear (ORB-SLAM's
SearchByProjection).

Brute-force matching of 1000 features against thousands of map points cost ~50 ms a frame and
lets a repeated texture match across the room; with a predicted pose each point only needs the
features within a few tens of pixels of its projection. Features are bucketed in a grid of
cells one radius wide, so a point looks at the 3×3 cells around it.
"""

from __future__ import annotations

import numpy as np

from twinslam.kernel_cache import njit
from twinslam.slam.bit_counting import popcount


@njit(cache=True)
def _match(feat_xy: np.ndarray, feat_desc: np.ndarray, cand_uv: np.ndarray,
           cand_desc: np.ndarray, radius: float, max_dist: int, ratio: float, width: int,
           height: int) -> tuple[np.ndarray, np.ndarray]:
    cell = max(radius, 1.0)
    gx = int(width / cell) + 1
    gy = int(height / cell) + 1
    n = feat_xy.shape[0]
    # counting sort of features into cells
    cell_of = np.empty(n, dtype=np.int64)
    counts = np.zeros(gx * gy + 1, dtype=np.int64)
    for i in range(n):
        cx = min(max(int(feat_xy[i, 0] / cell), 0), gx - 1)
        cy = min(max(int(feat_xy[i, 1] / cell), 0), gy - 1)
        cell_of[i] = cy * gx + cx
        counts[cell_of[i] + 1] += 1
    for c in range(gx * gy):
        counts[c + 1] += counts[c]
    order = np.empty(n, dtype=np.int64)
    fill = counts[:-1].copy()
    for i in range(n):
        order[fill[cell_of[i]]] = i
        fill[cell_of[i]] += 1
    # features copied in cell order: the scan below reads memory sequentially
    sxy = np.empty((n, 2))
    sdesc = np.empty((n, feat_desc.shape[1]), dtype=feat_desc.dtype)
    for s in range(n):
        sxy[s, 0], sxy[s, 1] = feat_xy[order[s], 0], feat_xy[order[s], 1]
        sdesc[s, :] = feat_desc[order[s], :]
    # best feature for every candidate point
    best_feat = np.full(n, -1, dtype=np.int64)      # per feature: winning candidate
    best_dist = np.full(n, 1 << 30, dtype=np.int64)
    r2 = radius * radius
    for j in range(cand_uv.shape[0]):
        u, v = cand_uv[j, 0], cand_uv[j, 1]
        if not (u >= 0.0 and v >= 0.0 and u < width and v < height):
            continue
        cx, cy = int(u / cell), int(v / cell)
        w0, w1, w2, w3 = cand_desc[j, 0], cand_desc[j, 1], cand_desc[j, 2], cand_desc[j, 3]
        d1, d2, f1 = 1 << 30, 1 << 30, -1
        for yy in range(max(cy - 1, 0), min(cy + 2, gy)):
            for xx in range(max(cx - 1, 0), min(cx + 2, gx)):
                c = yy * gx + xx
                for s in range(counts[c], counts[c + 1]):
                    du, dv = sxy[s, 0] - u, sxy[s, 1] - v
                    if du * du + dv * dv > r2:
                        continue
                    d = (popcount(sdesc[s, 0] ^ w0) + popcount(sdesc[s, 1] ^ w1)
                         + popcount(sdesc[s, 2] ^ w2) + popcount(sdesc[s, 3] ^ w3))
                    if d < d1:
                        d2, d1, f1 = d1, d, order[s]
                    elif d < d2:
                        d2 = d
        if f1 < 0 or d1 > max_dist or (d2 < (1 << 30) and d1 >= ratio * d2):
            continue
        if d1 < best_dist[f1]:                       # one map point per feature
            best_dist[f1] = d1
            best_feat[f1] = j
    k = 0
    for i in range(n):
        if best_feat[i] >= 0:
            k += 1
    feats = np.empty(k, dtype=np.int64)
    cands = np.empty(k, dtype=np.int64)
    k = 0
    for i in range(n):
        if best_feat[i] >= 0:
            feats[k] = i
            cands[k] = best_feat[i]
            k += 1
    return feats, cands


def match_by_projection(feat_xy: np.ndarray, feat_desc: np.ndarray, cand_uv: np.ndarray,
                        cand_desc: np.ndarray, radius: float, max_dist: int, ratio: float,
                        shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """(feature indices, candidate indices) of matches: for each candidate, the closest
    descriptor among features within ``radius`` px of its projection, if within ``max_dist``
    bits and clearly better than the runner-up (``ratio``); each feature keeps its best
    candidate."""
    if feat_desc.shape[1:] != (32,) or cand_desc.shape[1:] != (32,):
        raise ValueError("ORB descriptors are 32 bytes (4 × 64-bit words) each")
    if len(feat_xy) == 0 or len(cand_uv) == 0:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    fd = np.ascontiguousarray(feat_desc).view(np.uint64)
    cd = np.ascontiguousarray(cand_desc).view(np.uint64)
    h, w = shape
    return _match(np.ascontiguousarray(feat_xy, dtype=np.float64), fd,
                  np.ascontiguousarray(cand_uv, dtype=np.float64), cd, float(radius),
                  int(max_dist), float(ratio), int(w), int(h))


@njit(cache=True)
def _visible(world: np.ndarray, active: np.ndarray, cw: np.ndarray, k: np.ndarray, width: int,
             height: int, z_min: float, z_max: float) -> tuple[np.ndarray, np.ndarray]:
    n = world.shape[0]
    ids = np.empty(n, dtype=np.int64)
    uv = np.empty((n, 2))
    m = 0
    for i in range(n):
        if not active[i]:
            continue
        x = cw[0, 0] * world[i, 0] + cw[0, 1] * world[i, 1] + cw[0, 2] * world[i, 2] + cw[0, 3]
        y = cw[1, 0] * world[i, 0] + cw[1, 1] * world[i, 1] + cw[1, 2] * world[i, 2] + cw[1, 3]
        z = cw[2, 0] * world[i, 0] + cw[2, 1] * world[i, 1] + cw[2, 2] * world[i, 2] + cw[2, 3]
        if z <= z_min or z >= z_max:
            continue
        u = k[0, 0] * x / z + k[0, 2]
        v = k[1, 1] * y / z + k[1, 2]
        if 0.0 <= u < width and 0.0 <= v < height:
            ids[m] = i
            uv[m, 0] = u
            uv[m, 1] = v
            m += 1
    return ids[:m].copy(), uv[:m].copy()


def visible_points(world: np.ndarray, active: np.ndarray, camera_to_world: np.ndarray,
                   k: np.ndarray, shape: tuple[int, int], depth_range: tuple[float, float]
                   ) -> tuple[np.ndarray, np.ndarray]:
    """(ids, pixel positions) of the active points in front of the camera, within the depth
    range and inside the image, in one pass over the map (numpy needs several temporaries of
    the whole map per frame, and the map grows to ~10⁵ points)."""
    cw = np.linalg.inv(camera_to_world)
    h, w = shape
    return _visible(np.ascontiguousarray(world), np.ascontiguousarray(active),
                    np.ascontiguousarray(cw),
                    np.ascontiguousarray(k, dtype=np.float64), int(w), int(h),
                    float(depth_range[0]), float(depth_range[1]))


def back_project(uv: np.ndarray, depth: np.ndarray, k: np.ndarray,
                 camera_to_world: np.ndarray) -> np.ndarray:
    """World positions (n×3) of pixels ``uv`` (n×2) seen at ``depth`` (n, metres) by a pinhole
    camera ``k`` at ``camera_to_world``: how keyframes turn depth readings into map points."""
    uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
    z = np.asarray(depth, dtype=np.float64)
    cam = np.column_stack([(uv[:, 0] - k[0, 2]) * z / k[0, 0],
                           (uv[:, 1] - k[1, 2]) * z / k[1, 1], z])
    return np.asarray(cam @ camera_to_world[:3, :3].T + camera_to_world[:3, 3])
