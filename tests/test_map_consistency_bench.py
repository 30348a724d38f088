"""The map-consistency benchmark's measure: two copies of one place that disagree show by how
much; a map moved as a whole, or keyframes that see different places, show nothing."""

from __future__ import annotations

import numpy as np

from bench.map_consistency import disagreement


def _at(x: float, z: float) -> np.ndarray:
    pose = np.eye(4)
    pose[0, 3], pose[2, 3] = x, z
    return pose


def test_two_copies_of_a_place_disagree_by_their_offset() -> None:
    truth = {0: _at(0.0, 0.0), 1: _at(5.0, 0.0), 900: _at(0.05, 0.0), 901: _at(5.0, 0.1)}
    archive = {0: truth[0], 1: truth[1]}
    # the way back's keyframes 10 cm off where the way out put the same place
    managed = {900: _at(0.15, 0.0), 901: _at(5.0, 0.1)}
    found = disagreement(archive, managed, truth)
    assert found.pairs == 2
    assert np.isclose(found.max_m, 0.1) and found.worst == (0, 900)
    # the whole map shifted 1 m: nothing disagrees
    shift = _at(1.0, 0.0)
    moved = disagreement({k: shift @ p for k, p in archive.items()},
                         {k: shift @ p for k, p in truth.items() if k >= 900}, truth)
    assert moved.pairs == 2 and moved.max_m < 1e-9
    # keyframes that truly see different places are no pair
    apart = disagreement({0: truth[0]}, {901: managed[901]}, truth)
    assert apart.pairs == 0 and np.isnan(apart.rms_m)
    # within one map, pairs closer in time than min_gap are left out
    both = {**archive, **managed}
    assert disagreement(both, both, truth, min_gap=300).pairs == 4
    assert disagreement(both, both, truth, min_gap=1000).pairs == 0
