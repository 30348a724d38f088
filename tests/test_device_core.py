"""The device's core without DDS: frame records split global ids from track ids, uploads carry
one id per feature, and a map update relabels the tracks the edge resolved (no duplicates),
drops the device's stale points, and keeps tracking on course."""

from __future__ import annotations

import numpy as np

from device_tracker.device_core import TRACK_BIT, DeviceTrackerCore
from twinslam.sequence_player.synthetic import SyntheticSequence
from twinslam.slam.map_update import MapSnapshot

SLOT = 10


def _track(core: DeviceTrackerCore, frames: list) -> list:
    return [core.track(f.color, f.depth, f.stamp, image=f"image {f.index}") for f in frames]


def test_map_update_relabels_resolved_tracks_and_keeps_tracking() -> None:
    seq = SyntheticSequence(3 * SLOT, seed=0)
    frames = list(seq)
    core = DeviceTrackerCore(seq.intrinsics, SLOT)
    results = _track(core, frames[:SLOT])
    assert results[-1].slot_done and not any(r.slot_done for r in results[:-1])
    records = core.take_slot()
    assert [r.frame_id for r in records] == list(range(SLOT))
    # before any map update the device knows only its own points
    assert all(len(r.map_point_ids) == 0 and len(r.track_ids) > 50 for r in records)
    assert all(int(t) & TRACK_BIT for r in records for t in r.track_ids)

    up = core.upload(5)
    assert up is not None and len(up.point_ids) == len(up.keypoints) == len(up.depths)
    observed = {int(i) for i in up.point_ids if i}
    assert observed == {int(i) for i in records[5].track_ids}

    # the edge turned the tracks frame 0 observes into map points 1..n, at their positions
    first = records[0].track_ids
    rows = np.array([int(np.flatnonzero(core.labels == t)[0]) for t in first])
    global_ids = np.arange(1, len(first) + 1, dtype=np.uint64)
    update = MapSnapshot(1, np.array([0], np.uint64), np.eye(4)[None], global_ids,
                      core.tracking.map.positions[rows].copy(),
                      core.tracking.map.descriptors[rows].copy(),
                      np.ones(len(first), np.uint32), [global_ids], first, global_ids)
    assert core.apply_map_update(update, 0)
    assert not core.apply_map_update(update, 0), "an old version must not apply twice"
    labels = core.labels
    assert len(set(labels.tolist())) == len(labels), "a point is held twice"
    assert set(global_ids.tolist()) <= set(labels.tolist())
    assert not set(first.tolist()) & set(labels.tolist()), "resolved tracks keep no track id"

    results = _track(core, frames[SLOT:2 * SLOT])
    later = core.take_slot()
    assert all(r.record.tracked for r in results)
    # the next slot observes the resolved points by their global ids
    assert np.mean([len(r.map_point_ids) > 0 for r in later]) > 0.5
    truth = [f.pose for f in frames[SLOT:2 * SLOT]]
    for r, gt in zip(results, truth, strict=True):
        rel = np.linalg.inv(frames[0].pose) @ gt
        assert np.linalg.norm(r.record.pose[:3, 3] - rel[:3, 3]) < 0.05
    # a slot's frames stay uploadable through the next slot, then are forgotten
    assert core.upload(0) is not None
    _track(core, frames[2 * SLOT:])
    core.take_slot()
    assert core.upload(SLOT - 1) is None and core.upload(SLOT) is not None
    # the image kept with an upload lives exactly as long as the upload
    assert core.upload_image(SLOT - 1) is None and core.upload_image(SLOT) == f"image {SLOT}"
    payload = core.upload(SLOT)
    assert payload is not None and payload.frame_id == SLOT and payload.slot == 1
    np.testing.assert_array_equal(payload.intrinsics, seq.intrinsics)


def test_a_frame_the_motion_model_loses_is_relocalised() -> None:
    seq = SyntheticSequence(12, seed=0)
    frames = list(seq)
    core = DeviceTrackerCore(seq.intrinsics, SLOT)
    _track(core, frames[:10])
    core.take_slot()
    wrong = np.eye(4)
    wrong[:3, 3] = [0.6, -0.4, 0.5]           # a motion model 80 cm off: nothing projects near
    core.tracking._velocity = wrong
    result = core.track(frames[10].color, frames[10].depth, frames[10].stamp)
    assert result.relocalised and result.record.tracked
    assert result.recovered and not result.lost_now          # what the node logs
    truth = np.linalg.inv(frames[0].pose) @ frames[10].pose
    assert np.linalg.norm(result.record.pose[:3, 3] - truth[:3, 3]) < 0.05
    after = core.track(frames[11].color, frames[11].depth, frames[11].stamp)
    assert after.record.tracked and not after.relocalised
    assert not after.recovered and not after.lost_now


def test_tracking_lost_and_recovered_are_reported_once_each() -> None:
    seq = SyntheticSequence(16, seed=1)
    frames = list(seq)
    core = DeviceTrackerCore(seq.intrinsics, SLOT)
    _track(core, frames[:10])
    core.take_slot()
    blank = np.zeros_like(frames[10].color)                 # a covered lens: nothing to match
    lost = [core.track(blank, None, f.stamp) for f in frames[10:13]]
    assert [r.record.tracked for r in lost] == [False] * 3
    assert [r.lost_now for r in lost] == [True, False, False] and core.lost
    back = core.track(frames[13].color, frames[13].depth, frames[13].stamp)
    assert back.record.tracked and back.recovered and not back.lost_now
    truth = np.linalg.inv(frames[0].pose) @ frames[13].pose
    assert np.linalg.norm(back.record.pose[:3, 3] - truth[:3, 3]) < 0.05


def test_own_points_stay_bounded_while_the_edge_is_silent() -> None:
    """No map update for six slots: the device keeps only the points it made in the last
    keep_slots slots (the edge can no longer get the older ones) and tracks on."""
    seq = SyntheticSequence(6 * SLOT, seed=3)
    frames = list(seq)
    core = DeviceTrackerCore(seq.intrinsics, SLOT, keep_slots=2)
    sizes = []
    for k in range(6):
        results = _track(core, frames[k * SLOT:(k + 1) * SLOT])
        assert all(r.record.tracked for r in results), f"slot {k} lost tracking"
        core.take_slot()
        assert core.created.min() >= k - 1, "points older than keep_slots slots were kept"
        sizes.append(len(core.tracking.map))
    assert max(sizes) < 3 * min(sizes[1:]), f"the local map kept growing: {sizes}"
    truth = np.linalg.inv(frames[0].pose) @ frames[-1].pose
    assert np.linalg.norm(results[-1].record.pose[:3, 3] - truth[:3, 3]) < 0.05
