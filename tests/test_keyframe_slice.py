"""A device's slice of its place's map: the keyframes the device holds, what its map update
carries and what its plans count frames against. A place of one device sets nothing apart,
and its slice is its map; a keyframe set apart (held by another device of the place) is out of
the device's map update, its covisibility and its lost-frame count, though the place keeps it."""

from __future__ import annotations

import numpy as np
import pytest

from edge_mapper.messages import map_update_message
from edge_mapper.slot_planner import FrameObservations, SlotConfig, SlotPlanner
from twinslam.policies.registry import make_policy
from twinslam.slam.back_end.keyframe_archive import KeyFrameArchive
from twinslam.slam.back_end.keyframe_map import KeyFrameMap
from twinslam.slam.back_end.keyframe_slice import KeyFrameSlice
from twinslam.slam.back_end.keyframe_store import KeyFrameStore
from twinslam.slot_protocol.lost_frame_rule import MIN_INLIERS


def _place(keyframes: int = 3, shared: int = 60, own: int = 40) -> KeyFrameMap:
    """``keyframes`` keyframes a step apart along x, each making ``shared + own`` points and
    seeing the last ``shared`` its predecessor made too: the newest keyframe's points are its
    own alone."""
    rng = np.random.default_rng(3)
    m = KeyFrameMap()
    previous: list[int] = []
    for kf in range(keyframes):
        pose = np.eye(4)
        pose[0, 3] = 0.1 * kf
        m.add_keyframe(kf, pose)
        fresh = m.add_points(rng.uniform(-1, 1, (shared + own, 3)) + np.array([0, 0, 3.0]),
                             rng.integers(0, 256, (shared + own, 32), dtype=np.uint8))
        seen = previous[-shared:] + fresh if previous else fresh
        m.observe_many(kf, seen, [[320.0, 240.0]] * len(seen), [3.0] * len(seen))
        previous = fresh
    return m


def test_a_slice_that_sets_nothing_apart_is_its_map() -> None:
    """A place of one device: the slice reads the map itself — the same dicts, the same point
    rows, the same covisibility — so what a device's readers compute does not change."""
    m = _place()
    held = KeyFrameSlice(m)
    assert held.whole and held.keyframes is m.keyframes and held.points is m.points
    assert held.keyframe_ids() == [0, 1, 2]
    for mine, its in zip(held.point_rows(), m.columns.by_id(), strict=True):
        np.testing.assert_array_equal(mine, its)
    np.testing.assert_array_equal(held.covisibility(), m.covisibility())


def test_a_keyframe_set_apart_leaves_the_slice_and_the_points_only_it_sees() -> None:
    """Keyframe 2 held by another device only: this slice holds 0 and 1, the points they see
    (the 100 only 2 sees not among them, the 60 it shares with 1 still), and covisibility over
    0 and 1; the place's map still keeps all three and every point."""
    m = _place()
    held = KeyFrameSlice(m)
    held.set_apart([2])
    assert not held.whole and held.apart == frozenset({2})
    assert held.keyframe_ids() == [0, 1] and not held.holds(2) and held.holds(1)
    assert sorted(m.keyframes) == [0, 1, 2]
    expected = sorted(m.keyframes[0].points | m.keyframes[1].points)
    assert held.point_ids().tolist() == expected and sorted(held.points) == expected
    assert len(held.points) == len(m.points) - 100
    ids, rows = held.point_rows()
    np.testing.assert_array_equal(m.columns.positions[rows], m.positions_of(ids))
    np.testing.assert_array_equal(held.covisibility(), m.covisibility([0, 1]))
    held.take_in([2])
    assert held.whole and held.keyframe_ids() == [0, 1, 2]


def test_ids_the_place_does_not_keep_are_never_set_apart() -> None:
    """Setting apart a keyframe the place does not keep changes nothing; one the store
    archives is forgotten, so a keyframe entering the place later under its id is held."""
    store = KeyFrameStore(_place(), KeyFrameArchive(capacity=10))
    held = store.slice
    held.set_apart([7])
    assert held.whole and held.apart == frozenset()
    held.set_apart([2])
    store.leave_slice([2], slot=3)
    store.managed.add_keyframe(2, np.eye(4))
    assert held.holds(2) and held.whole


def test_the_map_update_of_a_slice_carries_its_keyframes_and_their_points_only() -> None:
    """What goes to the device is its slice: keyframe 2, held by another device, and the 100
    points only it sees are not in the update; a track resolved to one of those points is
    not either (the device could not place it)."""
    m = _place()
    held = KeyFrameSlice(m)
    held.set_apart([2])
    only_two = sorted(m.keyframes[2].points - m.keyframes[1].points)
    shared_one = sorted(m.keyframes[1].points)[0]
    msg = map_update_message(held, slot=4, version=9, stamp=1.0,
                             tracks={5: only_two[0], 6: shared_one})
    assert msg.keyframe_ids.tolist() == [0, 1]
    assert msg.point_ids.tolist() == held.point_ids().tolist()
    assert not set(only_two) & set(msg.point_ids.tolist())
    assert msg.track_point_ids.tolist() == [shared_one]
    whole = map_update_message(m, slot=4, version=9, stamp=1.0)
    assert len(whole.point_ids) == len(msg.point_ids) + len(only_two)


def test_a_plan_over_a_slice_counts_a_frame_lost_where_only_a_keyframe_set_apart_serves_it(
) -> None:
    """A frame that sees only keyframe 2's own points is served by the place's map but not by
    the device's slice: planned over the slice it is lost, over the whole map it is not."""
    m = _place()
    only_two = frozenset(m.keyframes[2].points - m.keyframes[1].points)
    assert len(only_two) >= MIN_INLIERS
    frames = [FrameObservations(10, frozenset(m.keyframes[0].points)),
              FrameObservations(11, only_two)]
    held = KeyFrameSlice(m)
    held.set_apart([2])
    over_slice = SlotPlanner(held, make_policy("lff"), SlotConfig(vmax=4)).plan(
        0, frames, rate_mbps=40.0, rate_state=1, rate_history=[1])
    over_map = SlotPlanner(m, make_policy("lff"), SlotConfig(vmax=4)).plan(
        0, frames, rate_mbps=40.0, rate_state=1, rate_history=[1])
    assert over_slice.lost == (False, True) and over_map.lost == (False, False)
    assert over_slice.observation.map_frames == [0, 1]


@pytest.mark.parametrize("evicted", [[0], [0, 2]])
def test_a_stores_slice_follows_its_evictions_and_restores(evicted: list[int]) -> None:
    """A store of one device: what leaves the slice for the archive leaves the map, and a
    restore brings it back into both — the slice stays the whole map throughout."""
    m = _place()
    store = KeyFrameStore(m, KeyFrameArchive(capacity=10))
    store.leave_slice(evicted, slot=3)
    assert store.slice.whole and store.slice.keyframe_ids() == sorted(m.keyframes)
    assert not set(evicted) & set(store.slice.keyframe_ids())
    store.enter_slice([store.archive.take(k) for k in evicted])
    assert store.slice.whole and store.slice.keyframe_ids() == [0, 1, 2]


def _two_devices() -> tuple[KeyFrameStore, KeyFrameSlice, KeyFrameSlice]:
    """A place's store whose first device holds keyframes 0–2 and a second device joined
    holding keyframes 1 and 2 of them."""
    store = KeyFrameStore(_place(), KeyFrameArchive(capacity=10))
    return store, store.slice, store.add_slice([1, 2])


def test_a_joining_device_holds_what_its_slice_names_and_its_own_new_keyframes_only() -> None:
    """The second slice holds 1 and 2, not 0; a keyframe entering the map for the second
    device is the second's alone — the first device's map update does not carry it."""
    store, first, second = _two_devices()
    assert first.keyframe_ids() == [0, 1, 2] and second.keyframe_ids() == [1, 2]
    store.managed.add_keyframe(3, np.eye(4))
    store.entered([3], by=second)
    assert second.keyframe_ids() == [1, 2, 3] and first.keyframe_ids() == [0, 1, 2]
    assert store.held_elsewhere(3, first) and not store.held_elsewhere(0, first)


def test_a_keyframe_another_device_holds_stays_in_the_map_when_one_evicts_it() -> None:
    """The second device evicts keyframe 1, which the first still holds: it stays in the map
    with its points, set apart from the second slice, nothing archived; the first device
    evicting keyframe 0, which no other holds, archives it and drops the points only it
    saw."""
    store, first, second = _two_devices()
    points = len(store.managed.points)
    assert store.leave_slice([1], slot=4, by=second) == ([], 0)
    assert 1 in store.managed.keyframes and 1 not in store.archive
    assert second.keyframe_ids() == [2] and first.keyframe_ids() == [0, 1, 2]
    assert len(store.managed.points) == points
    forgotten, orphans = store.leave_slice([0], slot=5, by=first)
    assert forgotten == [] and orphans == 40 and 0 in store.archive
    assert first.keyframe_ids() == [1, 2] and second.keyframe_ids() == [2]


def test_a_device_takes_in_another_devices_keyframe_from_the_place_and_a_restore_alone(
) -> None:
    """The second device takes keyframe 0 from the map as it is — no archive, no new point;
    then, keyframe 0 archived by both, a restore for the second device brings it back into
    the map for the second slice only."""
    store, first, second = _two_devices()
    points = len(store.managed.points)
    assert store.take_from_place([0, 2, 9], by=second) == [0]
    assert second.keyframe_ids() == [0, 1, 2] and len(store.managed.points) == points
    store.leave_slice([0], slot=6, by=first)
    assert 0 in store.managed.keyframes and first.keyframe_ids() == [1, 2]
    store.leave_slice([0], slot=7, by=second)
    assert 0 in store.archive and 0 not in store.managed.keyframes
    store.enter_slice([store.archive.take(0)], by=second)
    assert second.keyframe_ids() == [0, 1, 2] and first.keyframe_ids() == [1, 2]
