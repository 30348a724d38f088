"""Keys found in a sorted id array: the index where each is, and whether it is there at all
(before the first id, between two, past the last, and in an empty array)."""

from __future__ import annotations

import numpy as np

from twinslam.slam.sorted_ids import find_sorted


def test_keys_are_found_where_they_stand_and_absent_ones_are_told_apart() -> None:
    ids = np.array([3, 7, 20, 41], dtype=np.int64)
    keys = np.array([7, 1, 41, 8, 99, 3, -5], dtype=np.int64)
    at, found = find_sorted(ids, keys)
    assert found.tolist() == [True, False, True, False, False, True, False]
    assert ids[at[found]].tolist() == [7, 41, 3]
    at, found = find_sorted(np.zeros(0, dtype=np.int64), keys)
    assert not found.any()
