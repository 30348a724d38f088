"""The simulator's running count of the map's points gives the device's rule the
same shared-point counts as marking the map afresh, whatever sequence of maps it is moved
through (uploads, evictions, a place seen twice, an empty map, a restored snapshot)."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from twinslam.covisibility.dataset import CovisibilityDataset
from twinslam.covisibility.map_points import MapPointCounts

#: 12 frames over 40 points, overlapping as a walk's frames do
DATA = CovisibilityDataset.from_sets([set(range(3 * i, 3 * i + 8)) | {39 - i}
                                      for i in range(12)])


@settings(max_examples=60, deadline=None)
@given(st.lists(st.lists(st.integers(0, 11), max_size=8), min_size=1, max_size=8))
def test_counts_follow_any_sequence_of_maps(maps: list[list[int]]) -> None:
    counts = MapPointCounts(DATA)
    rows = np.arange(12)
    for m in maps:
        expected = DATA.shared_points(np.array(m, dtype=np.int64), rows)
        assert counts.shared(np.array(m, dtype=np.int64), rows).tolist() == expected.tolist()
        for need in (1, 4, 9):
            assert (counts.reaching(np.array(m, dtype=np.int64), rows, need).tolist()
                    == (expected >= need).tolist())


def test_a_frame_in_the_map_twice_still_counts_each_point_once() -> None:
    counts = MapPointCounts(DATA)
    twice = counts.shared(np.array([4, 4, 5]), np.array([4]))
    assert twice.tolist() == [DATA.points(4).size]
    once = counts.shared(np.array([4, 5]), np.array([4]))      # one of the two leaves
    assert once.tolist() == [DATA.points(4).size]
    assert counts.shared(np.array([], dtype=np.int64), np.array([4])).tolist() == [0]
