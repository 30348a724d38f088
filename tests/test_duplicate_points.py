"""The share of a map's points that are there twice: a look-alike within 5 cm counts, a
different corner close by or a look-alike far away does not; a live run reports it over the
map updates it received."""

from __future__ import annotations

import numpy as np

from twinslam.live.report import map_duplicate_share
from twinslam.live.run_log import RunLog
from twinslam.slam.duplicate_points import duplicate_share
from twinslam.slam.map_update import MapSnapshot

SAME, OTHER = np.zeros(32, np.uint8), np.full(32, 255, np.uint8)


def test_duplicate_share_counts_look_alikes_close_by() -> None:
    positions = np.array([[0.0, 0.0, 3.0],
                          [0.02, 0.0, 3.0],                 # its copy, 2 cm off
                          [0.0, 0.03, 3.0],                 # close, but another corner
                          [1.0, 0.0, 3.0]])                 # alike, but far
    assert duplicate_share(positions, np.array([SAME, SAME, OTHER, SAME])) == 0.5
    # one keyframe sees the first two: two features of one image, not the corner twice
    seen_by = [{1}, {1, 2}, {2}, {3}]
    assert duplicate_share(positions, np.array([SAME, SAME, OTHER, SAME]), seen_by) == 0.0
    assert duplicate_share(positions, np.array([SAME, SAME, OTHER, SAME]),
                           [{1}, {2}, {2}, {3}]) == 0.5
    assert np.isnan(duplicate_share(np.zeros((0, 3)), np.zeros((0, 32), np.uint8)))


def _snapshot(positions: list[list[float]], descriptors: list[np.ndarray]) -> MapSnapshot:
    n = len(positions)
    return MapSnapshot(1, np.zeros(0, np.uint64), np.zeros((0, 4, 4)),
                       np.arange(1, n + 1, dtype=np.uint64), np.array(positions, float),
                       np.array(descriptors, np.uint8), np.ones(n, np.uint32))


def test_a_run_reports_the_duplicate_share_of_its_map_updates_by_their_points() -> None:
    """One update of four points, two of them one corner, one of four different corners: two
    of the run's eight points were there twice."""
    record = RunLog()
    record.maps[0] = _snapshot([[0, 0, 3], [0.01, 0, 3], [1, 0, 3], [2, 0, 3]],
                               [SAME, SAME, OTHER, SAME])
    record.maps[1] = _snapshot([[0, 0, 3], [1, 0, 3], [2, 0, 3], [3, 0, 3]],
                               [SAME, SAME, SAME, SAME])
    assert map_duplicate_share(record) == 2 / 8
    # the update says which keyframe saw which points: one keyframe saw both copies
    record.maps[0].keyframe_points = [np.array([1, 2], np.uint64), np.array([3, 4], np.uint64)]
    assert map_duplicate_share(record) == 0.0
    assert np.isnan(map_duplicate_share(RunLog()))
