"""One back end for a place's devices: each device's keyframes enter the place's map under its
tag and its slice, read with its camera; a keyframe one device evicts stays while another
holds it; a restore enters one device's slice; a merge's motion moves every device's frame
from its own next map version; a device's map joins its place's moved, tagged, and its device
goes on in it."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from twinslam.slam.back_end.device_record import DeviceRecord
from twinslam.slam.back_end.foreign_keyframes import foreign_tag
from twinslam.slam.back_end.keyframe_archive import ArchivedKeyFrame
from twinslam.slam.back_end.loop_closing import ACROSS_GAP_SLOTS
from twinslam.slam.back_end.map_back_end import BackEndConfig, MapBackEnd
from twinslam.slam.back_end.place_joining import join_into_place
from twinslam.slam.keyframe import TRACK_ID_BIT, KeyFramePayload
from twinslam.slot_protocol.map_entry import RESTORED, UPLOADED

FIRST = np.array([[525.0, 0, 319.5], [0, 525.0, 239.5], [0, 0, 1]])
SECOND = np.array([[450.0, 0, 319.5], [0, 450.0, 239.5], [0, 0, 1]])
TAG = foreign_tag(1)


def _pose(x: float) -> np.ndarray:
    pose = np.eye(4)
    pose[0, 3] = x
    return pose


def _upload(kf_id: int, x: float, k: np.ndarray, slot: int, seed: int) -> KeyFramePayload:
    """A keyframe at ``x`` of 60 corners 3–5 m ahead, reported as new tracks 1–60."""
    rng = np.random.default_rng(seed)
    cam = rng.uniform([-1.2, -0.9, 3.0], [1.2, 0.9, 5.0], (60, 3))
    uv = cam @ k.T
    return KeyFramePayload(
        frame_id=kf_id, slot=slot, stamp=float(slot), pose=_pose(x), intrinsics=k,
        keypoints=(uv[:, :2] / uv[:, 2:]).astype(np.float32),
        depths=cam[:, 2].astype(np.float32),
        descriptors=rng.integers(0, 256, (60, 32), dtype=np.uint8),
        point_ids=(TRACK_ID_BIT | np.arange(1, 61, dtype=np.uint64)).astype(np.uint64))


def _place() -> tuple[MapBackEnd, DeviceRecord]:
    """A place's back end with its first device's keyframes 1 and 2 and the second device's
    (tagged) 1 and 2, 3 m along, where a merge placed its first camera."""
    back_end = MapBackEnd(BackEndConfig(ba_window=0), FIRST)
    second = back_end.add_device(TAG, SECOND, origin=_pose(3.0))
    for n in (1, 2):
        assert not back_end.integrate(_upload(n, 0.05 * n, FIRST, n, seed=n), -1).refused
        report = back_end.integrate(_upload(TAG | n, 3.0 + 0.05 * n, SECOND, n, seed=10 + n),
                                    -1, second)
        assert not report.refused
    return back_end, second


def test_each_devices_keyframes_enter_the_place_in_its_own_slice_with_its_camera() -> None:
    back_end, second = _place()
    first = back_end.device
    assert set(back_end.map.keyframes) == {1, 2, TAG | 1, TAG | 2}
    assert first.slice.keyframe_ids() == [1, 2]
    assert second.slice.keyframe_ids() == [TAG | 1, TAG | 2]
    assert first.entered == {1: (1, UPLOADED), 2: (2, UPLOADED)}
    assert second.entered == {TAG | 1: (1, UPLOADED), TAG | 2: (2, UPLOADED)}
    assert back_end.map.keyframes[1].intrinsics is None          # the place's first camera
    np.testing.assert_array_equal(back_end.map.keyframes[TAG | 1].intrinsics, SECOND)
    np.testing.assert_array_equal(back_end.camera_of(TAG | 2).intrinsics, SECOND)
    # each device's tracks 1-60 are its own corners: the second device's points are new
    assert not back_end.map.keyframes[1].points & back_end.map.keyframes[TAG | 1].points
    assert [t for t, _ in back_end.keyframe_trajectory(second)] == [1.0, 2.0]


def test_a_keyframe_one_device_evicts_stays_while_another_holds_it_and_a_restore_is_ones()\
        -> None:
    back_end, second = _place()
    first = back_end.device
    assert back_end.store.take_from_place([1], second.slice) == [1]
    back_end.evict_to_archive([1], slot=3)                 # the first device lets it go
    assert 1 in back_end.map.keyframes and second.slice.holds(1)
    assert not first.slice.holds(1) and 1 not in first.entered
    back_end.evict_to_archive([1], slot=4, device=second)  # and then the second: archived
    assert 1 not in back_end.map.keyframes and 1 in back_end.archive
    back_end.restore([1], [], slot=5, device=second)
    assert second.slice.holds(1) and not first.slice.holds(1)
    assert second.entered[1] == (5, RESTORED) and 1 not in first.entered


def test_a_merges_motion_moves_every_devices_frame_from_its_own_next_version() -> None:
    back_end, second = _place()
    first = back_end.device
    first.version, second.version = 3, 7
    motion = _pose(1.5)
    back_end.align(motion)
    for device, version in ((first, 3), (second, 7)):
        np.testing.assert_allclose(device.frame_correction_at(version), np.eye(4))
        np.testing.assert_allclose(device.frame_correction_at(version + 1), motion)
    np.testing.assert_allclose(first.origin, motion)
    np.testing.assert_allclose(second.origin, motion @ _pose(3.0))
    np.testing.assert_allclose(back_end.map.keyframes[TAG | 1].pose, motion @ _pose(3.05))


def test_a_loops_correction_moves_each_device_by_its_own_walks_head() -> None:
    back_end, second = _place()
    corrections = {1: _pose(0.01), 2: _pose(0.02), TAG | 1: _pose(0.1), TAG | 2: _pose(0.2)}
    np.testing.assert_allclose(back_end.device.head_of(corrections), _pose(0.02))
    np.testing.assert_allclose(second.head_of(corrections), _pose(0.2))
    assert second.head_of({1: _pose(0.01)}) is None        # none of its keyframes moved


def test_a_device_tag_is_one_no_other_device_of_the_place_has() -> None:
    back_end, _ = _place()
    for taken in (0, TAG, TAG | 5):
        with pytest.raises(ValueError):
            back_end.add_device(taken)


def _joining_map() -> MapBackEnd:
    """The second device's map of its own: keyframes 1–3 of one set of corners (its tracks
    1–60), 1 archived since, the device sent map version 5."""
    joining = MapBackEnd(BackEndConfig(ba_window=0), SECOND)
    for n in (1, 2, 3):
        assert not joining.integrate(_upload(n, 0.05 * n, SECOND, n, seed=20 + n), -1).refused
    joining.evict_to_archive([1], slot=3)
    joining.device.version = 5
    return joining


def test_a_joining_map_enters_its_place_moved_and_tagged_and_its_device_goes_on_in_it() -> None:
    place = MapBackEnd(BackEndConfig(ba_window=0), FIRST)
    for n in (1, 2):
        assert not place.integrate(_upload(n, 0.05 * n, FIRST, n, seed=n), -1).refused
    joining = _joining_map()
    alignment = _pose(3.0) @ np.array([[0.0, -1, 0, 0], [1, 0, 0, 0], [0, 0, 1, 0],
                                       [0, 0, 0, 1]])
    points_before = {k: set(kf.points) for k, kf in joining.map.keyframes.items()}
    a_point = next(iter(points_before[3]))
    [record], fused = join_into_place(place, joining, TAG, alignment)
    assert not fused                        # two walls of their own: no corner of the place's

    assert record.slice.keyframe_ids() == [TAG | 2, TAG | 3]
    assert place.device.slice.keyframe_ids() == [1, 2]
    for k in (2, 3):
        moved = place.map.keyframes[TAG | k]
        np.testing.assert_allclose(moved.pose, alignment @ joining.map.keyframes[k].pose)
        assert moved.points == {TAG | p for p in points_before[k]}
        np.testing.assert_array_equal(moved.intrinsics, SECOND)
    before = joining.map.points[a_point].position
    np.testing.assert_allclose(place.map.points[TAG | a_point].position,
                               alignment[:3, :3] @ before + alignment[:3, 3])
    archived = place.archive.get(TAG | 1)
    np.testing.assert_allclose(archived.pose, alignment @ joining.archive.get(1).pose)
    assert set(archived.point_ids.tolist()) == {TAG | p for p in points_before[2]}
    assert record.entered == {TAG | 2: (2, UPLOADED), TAG | 3: (3, UPLOADED)}
    assert record.keyframe_stamps == {TAG | 1: 1.0, TAG | 2: 2.0, TAG | 3: 3.0}
    assert record.version == 5
    np.testing.assert_allclose(record.frame_correction_at(5), np.eye(4))
    np.testing.assert_allclose(record.frame_correction_at(6), alignment)
    np.testing.assert_allclose(record.origin, alignment)

    # its next keyframe, posed on the version before the join: moved, its tracks found
    report = place.integrate(_upload(TAG | 4, 0.2, SECOND, 4, seed=24), 5, record)
    assert not report.refused and report.tracked == 60 and report.created_from_tracks == 0
    np.testing.assert_allclose(place.map.keyframes[TAG | 4].pose, alignment @ _pose(0.2))
    assert record.slice.holds(TAG | 4) and not place.device.slice.holds(TAG | 4)
    # its archived keyframe comes back into its slice, on the points it saw
    place.restore([TAG | 1], [], slot=6, device=record)
    assert record.slice.holds(TAG | 1) and record.entered[TAG | 1] == (6, RESTORED)
    assert place.map.keyframes[TAG | 1].points == {TAG | p for p in points_before[2]}


def test_a_map_holding_another_devices_copies_or_a_taken_tag_does_not_join() -> None:
    place = MapBackEnd(BackEndConfig(ba_window=0), FIRST)
    joining = _joining_map()
    copy = ArchivedKeyFrame.of(joining.map, 2, 4)
    joining.adopt([dataclasses.replace(copy, id=foreign_tag(5) | 2)])
    with pytest.raises(ValueError, match="copies"):
        join_into_place(place, joining, TAG, np.eye(4))
    with pytest.raises(ValueError, match="rigid motion"):
        join_into_place(place, _joining_map(), TAG, np.full((4, 4), np.nan))
    # a place that has the tag already: refused before anything moved
    join_into_place(place, _joining_map(), TAG, np.eye(4))
    keyframes = set(place.map.keyframes)
    with pytest.raises(ValueError, match="not free"):
        join_into_place(place, _joining_map(), TAG, np.eye(4))
    assert set(place.map.keyframes) == keyframes and len(place.devices) == 2


def test_a_restore_takes_a_keyframe_another_device_holds_as_it_is() -> None:
    back_end, second = _place()
    first = back_end.device
    points = set(back_end.map.keyframes[2].points)
    back_end.restore([2], [TAG | 1], slot=6, device=second)
    assert second.slice.holds(2) and first.slice.holds(2)          # held by both now
    assert back_end.map.keyframes[2].points == points               # one keyframe, its points
    assert second.entered[2] == (6, RESTORED) and first.entered[2] == (2, UPLOADED)
    assert not second.slice.holds(TAG | 1) and TAG | 1 in back_end.archive


def test_a_walks_loop_may_close_with_the_other_walks_keyframes_of_a_few_slots_before(
        ) -> None:
    """In a place of several devices a walk's loop may close with another walk's keyframe
    (the later comer bends towards the place another device mapped), but only with one its
    device integrated ACROSS_GAP_SLOTS of its own slots or more before its newest — a walk
    still there is still moving it — never with its own walk's (those are its own loops),
    and not at all with ``loops_across_devices`` off."""
    back_end, second = _place()                      # slots 1 and 2 of each device
    assert back_end._across(back_end.keyframe_poses(), 0, TAG) == frozenset()
    later = 1 + ACROSS_GAP_SLOTS                     # the first device walks on
    assert not back_end.integrate(_upload(3, 0.15, FIRST, later, seed=3), -1).refused
    assert back_end._across(back_end.keyframe_poses(), 0, TAG) == {1}
    assert back_end._across(back_end.keyframe_poses(), 0, 0) == frozenset()
    report = back_end.integrate(_upload(TAG | 3, 3.15, SECOND, 2 + ACROSS_GAP_SLOTS, seed=13),
                                -1, second)
    assert not report.refused
    assert back_end._across(back_end.keyframe_poses(), 0, 0) == {TAG | 1, TAG | 2}
    back_end.config = dataclasses.replace(back_end.config, loops_across_devices=False)
    assert back_end._across(back_end.keyframe_poses(), 0, TAG) == frozenset()


def test_a_place_handed_over_keeps_its_first_devices_keyframes_read_with_its_camera() -> None:
    back_end, second = _place()
    first = back_end.device
    back_end.restore([2], [], slot=3, device=second)        # keyframe 2 held by both
    with pytest.raises(ValueError, match="hands it over"):
        back_end.remove_device(first, 4)
    back_end.hand_over(second, slot=4)
    assert back_end.device is second and back_end.devices == [second]
    assert 1 in back_end.archive and back_end.slice.holds(2)   # what only it held: archived
    assert back_end.store.slices == [second.slice]
    # the first device's keyframes are still read with its camera; the leading device's own
    # (tagged) name theirs
    np.testing.assert_array_equal(back_end.k, FIRST)
    np.testing.assert_array_equal(back_end.camera_of(2).intrinsics, FIRST)
    assert not back_end.integrate(_upload(TAG | 3, 3.15, SECOND, 5, seed=13), -1,
                                  second).refused
    np.testing.assert_array_equal(back_end.camera_of(TAG | 3).intrinsics, SECOND)
    with pytest.raises(ValueError, match="another device"):
        back_end.hand_over(second, slot=5)
