"""One device's keyframes at the edge as one store: the slice the device holds and the
archive. A keyframe the policy evicts leaves the slice, not the store; a restore brings it back
with the points it saw; the whole store is what a merge looks in and what the pose graphs and
checkpoints list."""

from __future__ import annotations

import numpy as np
import pytest

from twinslam.slam.back_end.keyframe_archive import KeyFrameArchive
from twinslam.slam.back_end.keyframe_map import KeyFrameMap
from twinslam.slam.back_end.keyframe_store import KeyFrameStore


def _pose(x: float) -> np.ndarray:
    pose = np.eye(4)
    pose[0, 3] = x
    return pose


def _store(keyframes: int = 3, shared: int = 4, own: int = 6) -> KeyFrameStore:
    """A slice of ``keyframes`` keyframes a step apart, each seeing ``shared`` points its
    neighbour sees too and ``own`` points of its own."""
    rng = np.random.default_rng(7)
    m = KeyFrameMap()
    previous: list[int] = []
    for kf in range(keyframes):
        m.add_keyframe(kf, _pose(0.1 * kf))
        fresh = m.add_points(rng.uniform(-1, 1, (shared + own, 3)) + np.array([0, 0, 3.0]),
                             rng.integers(0, 256, (shared + own, 32), dtype=np.uint8))
        seen = previous[-shared:] + fresh if previous else fresh
        m.observe_many(kf, seen, [[320.0, 240.0]] * len(seen), [3.0] * len(seen))
        previous = fresh
    return KeyFrameStore(m, KeyFrameArchive(capacity=10))


def test_an_evicted_keyframe_leaves_the_slice_not_the_store() -> None:
    """Keyframe 0 evicted: the device no longer holds it, the edge still keeps it where it
    was, and its points only it saw leave the managed map with it (kept in the archive)."""
    store = _store()
    before = store.poses()
    forgotten, orphans = store.leave_slice([0], slot=5)
    assert forgotten == [] and orphans == 6
    assert 0 in store and not store.in_slice(0) and store.in_slice(1)
    assert len(store) == 3 and sorted(store.ids()) == [0, 1, 2]
    assert store.archive.get(0).archived_slot == 5
    assert sorted(store.poses()) == [0, 1, 2]
    for kf, pose in store.poses().items():
        np.testing.assert_array_equal(pose, before[kf])


def test_a_restored_keyframe_comes_back_with_the_points_it_took() -> None:
    """Evicted, then taken back: the slice holds it again, with the 6 points only it saw
    (the 4 it shares with keyframe 1 never left), and the archive no longer does."""
    store = _store()
    points_before = set(store.managed.keyframes[0].points)
    store.leave_slice([0], slot=5)
    returned = store.enter_slice([store.archive.take(0)])
    assert sorted(returned) == [0] and len(returned[0]) == 6
    assert store.in_slice(0) and 0 not in store.archive
    assert store.managed.keyframes[0].points == points_before


def test_each_keyframes_point_set_is_the_same_in_the_slice_and_in_the_archive() -> None:
    """The pose graphs count the points two keyframes share over the whole store: evicting
    one of them must not change what it sees."""
    store = _store()
    before = {k: set(v.tolist()) for k, v in store.point_sets().items()}
    store.leave_slice([1], slot=2)
    after = {k: set(v.tolist()) for k, v in store.point_sets().items()}
    assert after == before
    assert len(after[0] & after[1]) == 4 and not after[0] & after[2]


def test_a_snapshot_holds_every_keyframe_and_changes_nothing() -> None:
    """What a merge looks in: the archive's keyframes and the slice's, as one archive that a
    later edit of the store does not reach."""
    store = _store()
    store.leave_slice([0], slot=1)
    snapshot = store.snapshot(slot=2)
    assert sorted(kf.id for kf in snapshot) == [0, 1, 2]
    assert len(store.archive) == 1 and sorted(store.managed.keyframes) == [1, 2]
    store.managed.keyframes[2].pose = _pose(9.0)
    assert snapshot.get(2).pose[0, 3] == pytest.approx(0.2)


def test_each_keyframes_descriptors_are_its_points_in_the_slice_and_in_the_archive() -> None:
    """What a restored map files in the keyframe database: every kept keyframe once, the
    archive's first, each with the descriptors of the points it sees — the same rows for a
    keyframe the slice holds as the archive would keep for it."""
    store = _store()
    held = {k: {bytes(row) for row in store.managed.descriptors_of(
        np.fromiter(kf.points, dtype=np.int64))} for k, kf in store.managed.keyframes.items()}
    store.leave_slice([0], slot=1)
    listed = list(store.descriptors())
    assert [k for k, _ in listed] == [0, 1, 2]
    for k, descriptors in listed:
        assert descriptors.shape == (len(held[k]), 32)
        assert {bytes(row) for row in descriptors} == held[k]
