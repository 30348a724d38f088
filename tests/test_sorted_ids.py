"""Keys found in a sorted id array: the index where each is, and whether it is there at all
(before the first id, between two, past the last, and in an empty array); and the ids a set of
keys holds, as a sort would list them."""

from __future__ import annotations

import numpy as np
import pytest

from twinslam.slam.sorted_ids import find_sorted, unique_ids, unique_ids_and_inverse


def test_keys_are_found_where_they_stand_and_absent_ones_are_told_apart() -> None:
    ids = np.array([3, 7, 20, 41], dtype=np.int64)
    keys = np.array([7, 1, 41, 8, 99, 3, -5], dtype=np.int64)
    at, found = find_sorted(ids, keys)
    assert found.tolist() == [True, False, True, False, False, True, False]
    assert ids[at[found]].tolist() == [7, 41, 3]
    at, found = find_sorted(np.zeros(0, dtype=np.int64), keys)
    assert not found.any()


def test_unique_ids_answer_as_a_sort_does_whether_the_ids_are_dense_or_far_apart() -> None:
    rng = np.random.default_rng(7)
    cases = [np.array([5, 3, 5, -2, 3, 9], dtype=np.int64),      # a track key among points
             rng.integers(1, 3000, 20_000),                       # a map's own ids: marked
             rng.integers(-10**9, 10**9, 400),                    # far apart: sorted
             np.array([(1 << 41) + 8, 3, (1 << 41) + 8, 3]),      # another device's ids
             np.array([11], dtype=np.uint64),
             np.zeros(0, dtype=np.int64)]
    for keys in cases:
        ids, inverse = unique_ids_and_inverse(keys)
        want_ids, want_inverse = np.unique(keys, return_inverse=True)
        assert ids.dtype == inverse.dtype == np.int64
        assert ids.tolist() == want_ids.tolist()
        assert inverse.tolist() == want_inverse.ravel().tolist()
        assert ids[inverse].tolist() == np.asarray(keys).tolist()
        assert unique_ids(keys).tolist() == want_ids.tolist()
    with pytest.raises(TypeError, match="integers"):
        unique_ids(np.array([1.5, 2.0]))
