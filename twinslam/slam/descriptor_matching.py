"""Matching ORB descriptors by descriptor alone (no pose to project with): relocalisation,
on the device against its map and at the edge against the archive, loop detection and the
map's look for duplicate points.

The two nearest train descriptors of every query come from faiss' exact binary index (the
archive's place recognition uses the same): one call that returns arrays. OpenCV's
``BFMatcher.knnMatch`` finds the same neighbours but hands back a Python object a match,
which cost the edge six times the search itself (``bench.edge_work``'s loop closer and
integration; BENCHMARKS.md). The matches are the same either way: a best neighbour tied
with the second fails the ratio test whichever of the two a search lists first.
"""

from __future__ import annotations

import numpy as np


def match_descriptors(query: np.ndarray, train: np.ndarray, max_hamming: int, ratio: float
                      ) -> tuple[np.ndarray, np.ndarray]:
    """(query indices, train indices) of the matches that pass Lowe's ratio test and the
    Hamming cap, at most one query per train descriptor (the first in query order)."""
    if not len(query) or len(train) < 2:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    # faiss loads with the first match, not with every importer of the front end
    import faiss

    query = np.ascontiguousarray(query, dtype=np.uint8)
    train = np.ascontiguousarray(train, dtype=np.uint8)
    index = faiss.IndexBinaryFlat(8 * train.shape[1])
    index.add(train)
    distance, nearest = index.search(query, 2)
    best, second = distance[:, 0], distance[:, 1]
    passed = (best <= max_hamming) & (best < ratio * second)
    q = np.flatnonzero(passed)
    t = nearest[passed, 0].astype(np.int64)
    _, first = np.unique(t, return_index=True)
    first.sort()
    return q[first], t[first]


def hamming_rows(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The Hamming distance of each row of ``a`` to the same row of ``b`` (ORB descriptors,
    n×32 uint8 each): the bits they differ in."""
    a = np.ascontiguousarray(a, dtype=np.uint8)
    b = np.ascontiguousarray(b, dtype=np.uint8)
    if a.ndim == 2 and a.shape == b.shape and a.shape[1] % 8 == 0:
        a, b = a.view(np.uint64), b.view(np.uint64)      # 4 words a row, not 32 bytes
    distance: np.ndarray = np.bitwise_count(np.bitwise_xor(a, b)).sum(axis=1, dtype=np.int64)
    return distance
