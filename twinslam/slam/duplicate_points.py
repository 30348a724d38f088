"""How much of a map is there twice: the share of its points with a look-alike close by that
no keyframe sees together with them.

A corner the map holds twice — made again from depth because a keyframe's feature was matched
to neither copy, brought back by a restore beside the walk's own, left behind where a
correction moved one copy and not the other — splits the device's matches between two points
that disagree, and shows in its pose solve's outliers. Two look-alike points one keyframe
observes both of are two features of one image (ORB finds a corner again at another level of
its pyramid, or a neighbouring pixel): not the wall twice, and not counted — on the synthetic
corridor they were three in four of the close look-alike pairs. Counted on the edge's map (the
map-consistency bench) and on every map update a live run received (its report), in one way.
"""

from __future__ import annotations

import math
from collections.abc import Collection, Sequence

import numpy as np
from scipy.spatial import cKDTree

from twinslam.slam.descriptor_matching import hamming_rows

#: a point with a look-alike this close is a duplicate (a wall twice in the map)
DUPLICATE_RADIUS_M = 0.05
#: descriptors this many bits apart at most look alike: the matchers' own cap
LOOK_ALIKE_BITS = 50


def duplicate_share(positions: np.ndarray, descriptors: np.ndarray,
                    seen_by: Sequence[Collection[int]] | None = None,
                    radius_m: float = DUPLICATE_RADIUS_M,
                    max_hamming: int = LOOK_ALIKE_BITS) -> float:
    """The share of the points (``positions`` n×3, ORB ``descriptors`` n×32 bytes) with
    another within ``radius_m`` whose descriptor is within ``max_hamming`` bits of theirs and
    that no keyframe observes together with them (``seen_by``: each point's keyframes; None:
    every close look-alike counts) (NaN: no point)."""
    xyz = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
    if not len(xyz):
        return math.nan
    desc = np.asarray(descriptors, dtype=np.uint8).reshape(len(xyz), -1)
    pairs = cKDTree(xyz).query_pairs(radius_m, output_type="ndarray")
    if not len(pairs):
        return 0.0
    apart = hamming_rows(desc[pairs[:, 0]], desc[pairs[:, 1]])
    alike = pairs[apart <= max_hamming]
    if seen_by is not None:
        alike = alike[[not set(seen_by[a]) & set(seen_by[b]) for a, b in alike.tolist()]]
    return float(len(np.unique(alike)) / len(xyz))
