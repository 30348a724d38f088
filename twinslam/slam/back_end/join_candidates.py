"""The map points a keyframe's new feature may join instead of making a point of its own: those
within the feature's reach in space and alike in descriptor, nearest in descriptor first.

Integration asks this for every free feature with a depth (:meth:`~twinslam.slam.back_end.
local_mapping.LocalMapping._alike_finder`). Two k-d trees and their sparse distance matrix
listed every (feature, point) pair within the largest reach — ~44 000 pairs a keyframe on the
7-Scenes walk, of which the Hamming test then kept a few hundred — and each list was built,
filtered and sorted as numpy arrays: ~2.1 ms a keyframe. One compiled pass instead files the
points in a grid of cells one largest reach wide, and looks at each feature's 27 cells around
it, keeping a pair only once it passes both tests: 0.9 ms.

Ties in descriptor distance go to the point the caller ranks first (``rank``): the edge ranks
the map's points by age, the point it has held longest first (a k-d tree's leaf order, which
reproduced the per-feature queries' choices, cost as much again as the search itself).
"""

from __future__ import annotations

import numpy as np

from twinslam.kernel_cache import njit
from twinslam.slam.bit_counting import popcount

#: grid cells along an axis the keys can tell apart (a point further out shares the border
#: cell: the distance test still holds, only the search looks at more points)
_CELLS = 1 << 21
_LOWEST = -(_CELLS // 2) + 2
_HIGHEST = _CELLS // 2 - 2


@njit(cache=True)
def _cell(x: float, size: float) -> int:
    c = np.floor(x / size)
    if not c >= _LOWEST:               # NaN too: every comparison with it is false
        c = _LOWEST
    if c > _HIGHEST:
        c = _HIGHEST
    return int(c) + _CELLS // 2


@njit(cache=True)
def _key(cx: int, cy: int, cz: int) -> int:
    return (cx * _CELLS + cy) * _CELLS + cz


@njit(cache=True)
def _candidates(features: np.ndarray, reach: np.ndarray, feature_words: np.ndarray,
                points: np.ndarray, point_words: np.ndarray, rank: np.ndarray,
                max_hamming: int) -> tuple[np.ndarray, np.ndarray]:
    m, n = features.shape[0], points.shape[0]
    size = 0.0
    for f in range(m):
        size = max(size, reach[f])
    size = max(size, 1e-9)
    keys = np.empty(n, dtype=np.int64)
    for j in range(n):
        keys[j] = _key(_cell(points[j, 0], size), _cell(points[j, 1], size),
                       _cell(points[j, 2], size))
    order = np.argsort(keys)
    sorted_keys = keys[order]
    counts = np.zeros(m, dtype=np.int64)
    out = np.empty(4 * m + 16, dtype=np.int64)
    filled = 0
    near = np.empty(n, dtype=np.int64)             # one feature's points, kept sorted
    apart = np.empty(n, dtype=np.int64)
    for f in range(m):
        x, y, z, r = features[f, 0], features[f, 1], features[f, 2], reach[f]
        cx, cy, cz = _cell(x, size), _cell(y, size), _cell(z, size)
        w0, w1, w2, w3 = (feature_words[f, 0], feature_words[f, 1], feature_words[f, 2],
                          feature_words[f, 3])
        found = 0
        for ix in range(cx - 1, cx + 2):
            for iy in range(cy - 1, cy + 2):
                lo = np.searchsorted(sorted_keys, _key(ix, iy, cz - 1))
                hi = np.searchsorted(sorted_keys, _key(ix, iy, cz + 2))
                for s in range(lo, hi):
                    j = order[s]
                    dx, dy, dz = points[j, 0] - x, points[j, 1] - y, points[j, 2] - z
                    if not np.sqrt(dx * dx + dy * dy + dz * dz) <= r:
                        continue
                    d = (popcount(point_words[j, 0] ^ w0) + popcount(point_words[j, 1] ^ w1)
                         + popcount(point_words[j, 2] ^ w2) + popcount(point_words[j, 3] ^ w3))
                    if d > max_hamming:
                        continue
                    at = found                     # insertion: by distance, then rank
                    while at > 0 and (apart[at - 1] > d or (apart[at - 1] == d
                                                            and rank[near[at - 1]] > rank[j])):
                        near[at], apart[at] = near[at - 1], apart[at - 1]
                        at -= 1
                    near[at], apart[at] = j, d
                    found += 1
        if filled + found > len(out):
            grown = np.empty(max(2 * len(out), filled + found), dtype=np.int64)
            grown[:filled] = out[:filled]
            out = grown
        out[filled:filled + found] = near[:found]
        filled += found
        counts[f] = found
    return out[:filled], counts


def join_candidates(features: np.ndarray, reach: np.ndarray, feature_descriptors: np.ndarray,
                    points: np.ndarray, point_descriptors: np.ndarray, rank: np.ndarray,
                    max_hamming: int) -> tuple[np.ndarray, np.ndarray]:
    """For each feature (``features`` (m, 3) world positions, ``feature_descriptors`` (m, 32)
    uint8 ORB), the points (``points`` (n, 3), ``point_descriptors`` (n, 32)) within its
    ``reach`` ((m,) metres) and at most ``max_hamming`` bits from its descriptor, nearest in
    descriptor first, ties by ascending ``rank`` ((n,) int). Returns (point rows, one list
    after another; how many each feature has ((m,) int64))."""
    xyz = np.ascontiguousarray(features, dtype=np.float64).reshape(-1, 3)
    where = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
    mine = np.ascontiguousarray(feature_descriptors, dtype=np.uint8)
    theirs = np.ascontiguousarray(point_descriptors, dtype=np.uint8)
    r = np.ascontiguousarray(reach, dtype=np.float64).reshape(-1)
    order = np.ascontiguousarray(rank, dtype=np.int64).reshape(-1)
    if mine.shape != (len(xyz), 32) or theirs.shape != (len(where), 32):
        raise ValueError(f"descriptors {mine.shape} and {theirs.shape} for {len(xyz)} "
                         f"features and {len(where)} points: ORB descriptors are 32 bytes")
    if len(r) != len(xyz) or len(order) != len(where):
        raise ValueError(f"{len(r)} reaches for {len(xyz)} features, {len(order)} ranks for "
                         f"{len(where)} points")
    if not len(xyz) or not len(where):
        return np.zeros(0, dtype=np.int64), np.zeros(len(xyz), dtype=np.int64)
    rows, counts = _candidates(xyz, r, mine.view(np.uint64), where, theirs.view(np.uint64),
                               order, int(max_hamming))
    return rows, counts
