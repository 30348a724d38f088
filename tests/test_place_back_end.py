"""One back end for a place's devices: each device's keyframes enter the place's map under its
tag and its slice, read with its camera; a keyframe one device evicts stays while another
holds it; a restore enters one device's slice; a merge's motion moves every device's frame
from its own next map version."""

from __future__ import annotations

import numpy as np
import pytest

from twinslam.slam.back_end.device_record import DeviceRecord
from twinslam.slam.back_end.foreign_keyframes import foreign_tag
from twinslam.slam.back_end.map_back_end import BackEndConfig, MapBackEnd
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
