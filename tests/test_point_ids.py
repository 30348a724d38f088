"""A keyframe's point ids share one 64-bit space: a map point's global id, or a device-local
track id marked by the top bit. Marking and unmarking round-trip, and the slot planner's key
for a track never equals a map point's key."""

from __future__ import annotations

import numpy as np

from edge_mapper.slot_planner import FrameObservations, SlotPlanner
from twinslam.policies.registry import make_policy
from twinslam.slam.back_end.keyframe_map import KeyFrameMap
from twinslam.slam.keyframe import as_track_ids, is_track, is_track_id, track_counters


def test_a_track_counter_round_trips_through_its_id() -> None:
    counters = np.array([0, 7, 2**40, 2**62], dtype=np.uint64)
    ids = as_track_ids(counters)
    assert is_track(ids).all() and all(is_track_id(int(i)) for i in ids)
    np.testing.assert_array_equal(track_counters(ids), counters.astype(np.int64))
    assert not is_track(np.array([0, 7, 2**62], dtype=np.uint64)).any()


def test_a_track_and_a_map_point_of_one_number_are_different_keys() -> None:
    planner = SlotPlanner(KeyFrameMap(), make_policy("lff"))
    frame = FrameObservations(1, frozenset({7}), frozenset(int(i) for i in as_track_ids(
        np.array([7], dtype=np.uint64))))
    keys = planner.points_of({1: frame}, 1)
    assert sorted(keys.tolist()) == [-8, 7]
