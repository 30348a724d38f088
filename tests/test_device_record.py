"""What the edge keeps of one device beside its place's map: tracks of its own, the frame of
each map version it was sent, and what a restart reads back of it."""

from __future__ import annotations

import numpy as np

from twinslam.slam.back_end.device_record import DeviceRecord
from twinslam.slam.back_end.keyframe_archive import KeyFrameArchive
from twinslam.slam.back_end.keyframe_map import KeyFrameMap
from twinslam.slam.back_end.keyframe_store import KeyFrameStore
from twinslam.slam.back_end.local_mapping import LocalMapping
from twinslam.slam.keyframe import TRACK_ID_BIT, KeyFramePayload
from twinslam.slot_protocol.map_entry import RESTORED, UPLOADED

K = np.array([[500.0, 0, 320], [0, 500, 240], [0, 0, 1]])
SHAPE = (480, 640)


def _pose(x: float) -> np.ndarray:
    pose = np.eye(4)
    pose[0, 3] = x
    return pose


def _record(store: KeyFrameStore, slice_=None) -> DeviceRecord:
    return DeviceRecord(slice_ or store.slice, LocalMapping(store.managed, K, SHAPE), SHAPE)


def _tracked_view(x: float, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A view from ``x`` of 80 corners of its own, reported as the device's tracks 1–80."""
    rng = np.random.default_rng(seed)
    cam = rng.uniform([-1.5, -1.0, 3.0], [1.5, 1.0, 5.0], (80, 3))
    uv = cam[:, :2] / cam[:, 2:] * 500 + [320, 240]
    descriptors = rng.integers(0, 256, (80, 32), dtype=np.uint8)
    tracks = (TRACK_ID_BIT | np.arange(1, 81, dtype=np.uint64)).astype(np.uint64)
    return uv, descriptors, cam[:, 2].copy(), tracks


def test_two_devices_of_one_place_keep_their_tracks_apart() -> None:
    # track ids are each device's own numbering: device B's track 5 is not device A's corner
    store = KeyFrameStore(KeyFrameMap(), KeyFrameArchive(10))
    first = _record(store)
    second = _record(store, store.add_slice(()))
    first.local_mapping.integrate(1, _pose(0.0), *_tracked_view(0.0, seed=1))
    a_points = set(store.managed.keyframes[1].points)
    report = second.local_mapping.integrate(1001, _pose(20.0), *_tracked_view(20.0, seed=2))
    b_points = set(store.managed.keyframes[1001].points)
    assert report.created_from_tracks == 80                    # every one a corner of its own
    assert len(a_points) == len(b_points) == 80 and not a_points & b_points
    track = int(TRACK_ID_BIT) | 5
    assert first.local_mapping.track_points[track] in a_points
    assert second.local_mapping.track_points[track] in b_points
    # each device's next keyframe finds its own tracks' points again
    again = second.local_mapping.integrate(1002, _pose(20.05), *_tracked_view(20.05, seed=2))
    assert again.created_from_tracks == 0
    assert set(store.managed.keyframes[1002].points) == b_points


def test_a_keyframe_posed_on_an_older_map_version_moves_by_what_the_map_went_through() -> None:
    record = _record(KeyFrameStore(KeyFrameMap(), KeyFrameArchive(10)))
    loop = _pose(0.3)
    record.version = 3
    record.frame_moved(loop)                           # a loop applied from version 4 on
    upload = KeyFramePayload(frame_id=7, slot=3, stamp=1.0, pose=_pose(1.0), intrinsics=K,
                             keypoints=np.zeros((0, 2)), depths=np.zeros(0),
                             descriptors=np.zeros((0, 32), dtype=np.uint8),
                             point_ids=np.zeros(0, dtype=np.uint64))
    np.testing.assert_allclose(record.in_current_frame(upload, 3).pose, loop @ _pose(1.0))
    assert record.in_current_frame(upload, 4) is upload      # posed on the corrected map
    assert record.in_current_frame(upload, -1) is upload     # version unknown: as it is
    record.version = 5
    record.frame_moved(_pose(0.1))
    np.testing.assert_allclose(record.moved_since(3), _pose(0.4), atol=1e-12)
    np.testing.assert_allclose(record.moved_since(5), _pose(0.1), atol=1e-12)


def test_a_restart_reads_back_the_device_as_the_place_keeps_it() -> None:
    store = KeyFrameStore(KeyFrameMap(), KeyFrameArchive(10))
    record = _record(store)
    for kf in (1, 2, 3):
        store.managed.add_keyframe(kf, _pose(kf))
    store.entered([1, 2, 3])
    record.entered.update({1: (0, UPLOADED), 2: (1, UPLOADED), 3: (2, RESTORED)})
    record.keyframe_stamps.update({1: 0.1, 2: 0.2, 3: 0.3, 9: 0.9})   # 9: forgotten since
    record.version = 1
    record.frame_moved(_pose(0.2))
    record.version = 4
    record.origin = _pose(-1.0)
    store.leave_slice([2], slot=3)                     # archived: kept, no longer held
    arrays = record.checkpoint_arrays(store)

    again = DeviceRecord.restored(store.slice, LocalMapping(store.managed, K, SHAPE), SHAPE,
                                  arrays)
    assert again.entered == {1: (0, UPLOADED), 3: (2, RESTORED)}
    assert again.keyframe_stamps == {1: 0.1, 2: 0.2, 3: 0.3}
    np.testing.assert_allclose(again.frame_correction, _pose(0.2))
    assert again.version == 4
    np.testing.assert_allclose(again.origin, _pose(-1.0))
    # a fresh device starts where its walk starts
    fresh = DeviceRecord.restored(store.slice, LocalMapping(store.managed, K, SHAPE), SHAPE, {})
    assert fresh.entered == {} and fresh.keyframe_stamps == {}
    np.testing.assert_allclose(fresh.frame_correction, np.eye(4))
