"""The points a new feature may join: every point within its reach and alike enough, nearest in
descriptor first, ties by the caller's rank — as a search of every (feature, point) pair finds
them."""

from __future__ import annotations

import numpy as np
import pytest

from twinslam.slam.back_end.join_candidates import join_candidates
from twinslam.slam.descriptor_matching import hamming_rows


def _every_pair(features: np.ndarray, reach: np.ndarray, feature_desc: np.ndarray,
                points: np.ndarray, point_desc: np.ndarray, rank: np.ndarray,
                max_hamming: int) -> list[list[int]]:
    lists = []
    for f in range(len(features)):
        near = np.flatnonzero(np.linalg.norm(points - features[f], axis=1) <= reach[f])
        apart = hamming_rows(point_desc[near], feature_desc[np.full(len(near), f)])
        keep = apart <= max_hamming
        near, apart = near[keep], apart[keep]
        lists.append(near[np.lexsort((rank[near], apart))].tolist())
    return lists


def _as_lists(rows: np.ndarray, counts: np.ndarray) -> list[list[int]]:
    ends = np.cumsum(counts)
    return [rows[end - n:end].tolist() for n, end in zip(counts, ends, strict=True)]


def test_the_candidates_are_those_of_a_search_of_every_pair_in_their_order() -> None:
    rng = np.random.default_rng(0)
    points = rng.uniform(-1.0, 1.0, (3000, 3))
    features = rng.uniform(-1.0, 1.0, (400, 3))
    reach = rng.uniform(0.03, 0.15, 400)           # a reach of its own for every feature
    # few distinct descriptors: many ties in Hamming distance, settled by the rank
    palette = rng.integers(0, 256, (6, 32), dtype=np.uint8)
    point_desc = palette[rng.integers(0, 6, 3000)]
    feature_desc = palette[rng.integers(0, 6, 400)]
    rank = rng.permutation(3000)
    rows, counts = join_candidates(features, reach, feature_desc, points, point_desc, rank,
                                   max_hamming=140)
    expected = _every_pair(features, reach, feature_desc, points, point_desc, rank, 140)
    assert _as_lists(rows, counts) == expected
    assert sum(len(e) > 1 for e in expected) > 100        # the ordering was put to the test


def test_points_far_outside_the_grid_or_without_a_position_are_handled() -> None:
    features = np.array([[0.0, 0.0, 0.0], [1e12, 0.0, 0.0]])
    points = np.array([[0.01, 0.0, 0.0], [np.nan, 0.0, 0.0], [1e12, 0.0, 0.02],
                       [-1e12, 0.0, 0.0]])
    desc = np.zeros((4, 32), dtype=np.uint8)
    rows, counts = join_candidates(features, np.array([0.05, 0.05]), desc[:2], points, desc,
                                   np.arange(4), max_hamming=0)
    assert _as_lists(rows, counts) == [[0], [2]]


def test_descriptors_that_are_not_orb_rows_are_refused() -> None:
    with pytest.raises(ValueError, match="32 bytes"):
        join_candidates(np.zeros((2, 3)), np.ones(2), np.zeros((2, 16), dtype=np.uint8),
                        np.zeros((3, 3)), np.zeros((3, 32), dtype=np.uint8), np.arange(3), 50)
    with pytest.raises(ValueError, match="ranks"):
        join_candidates(np.zeros((2, 3)), np.ones(2), np.zeros((2, 32), dtype=np.uint8),
                        np.zeros((3, 3)), np.zeros((3, 32), dtype=np.uint8), np.arange(2), 50)
