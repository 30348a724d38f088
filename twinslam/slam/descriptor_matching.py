"""Matching ORB descriptors by descriptor alone (no pose to project with): relocalisation,
on the device against its map and at the edge against the archive."""

from __future__ import annotations

import cv2
import numpy as np


def match_descriptors(query: np.ndarray, train: np.ndarray, max_hamming: int, ratio: float
                      ) -> tuple[np.ndarray, np.ndarray]:
    """(query indices, train indices) of the matches that pass Lowe's ratio test and the
    Hamming cap, at most one query per train descriptor (the first in query order)."""
    if not len(query) or len(train) < 2:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    pairs = cv2.BFMatcher(cv2.NORM_HAMMING).knnMatch(query, train, k=2)
    q_idx, t_idx = [], []
    for pair in pairs:
        if len(pair) == 2 and pair[0].distance <= max_hamming and \
                pair[0].distance < ratio * pair[1].distance:
            q_idx.append(pair[0].queryIdx)
            t_idx.append(pair[0].trainIdx)
    q = np.array(q_idx, dtype=np.int64)
    t = np.array(t_idx, dtype=np.int64)
    _, first = np.unique(t, return_index=True)
    first.sort()
    return q[first], t[first]


def hamming_rows(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The Hamming distance of each row of ``a`` to the same row of ``b`` (ORB descriptors,
    n×32 uint8 each): the bits they differ in."""
    return np.asarray(np.count_nonzero(
        np.unpackbits(np.asarray(a, dtype=np.uint8), axis=1)
        != np.unpackbits(np.asarray(b, dtype=np.uint8), axis=1), axis=1))
