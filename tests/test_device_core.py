"""The device's core without DDS: frame records split global ids from track ids, uploads carry
one id per feature, and a map update relabels the tracks the edge resolved (no duplicates),
drops the device's stale points, and keeps tracking on course."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from device_tracker.device_core import DeviceTrackerCore, relabelled, rows_of_points
from device_tracker.frame_log import frame_log_lines
from twinslam.sequences.synthetic import SyntheticSequence
from twinslam.slam.front_end.tracking import TrackingConfig
from twinslam.slam.keyframe import as_track_ids, is_track, is_track_id
from twinslam.slam.map_update import MapSnapshot

SLOT = 10


def _track(core: DeviceTrackerCore, frames: list) -> list:
    return [core.track(f.color, f.depth, f.stamp, image=f"image {f.index}") for f in frames]


def _first_frame_mapped(core: DeviceTrackerCore, records: list) -> MapSnapshot:
    """The edge's first map update as it would make it of the device's first slot: the tracks
    its frame 0 observes turned into map points 1..n at the device's positions."""
    first = records[0].track_ids
    rows = np.array([int(np.flatnonzero(core.labels == t)[0]) for t in first])
    global_ids = np.arange(1, len(first) + 1, dtype=np.uint64)
    return MapSnapshot(1, np.array([0], np.uint64), np.eye(4)[None], global_ids,
                       core.tracking.map.positions[rows].copy(),
                       core.tracking.map.descriptors[rows].copy(),
                       np.ones(len(first), np.uint32), [global_ids], first, global_ids)


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
    assert all(is_track_id(t) for r in records for t in r.track_ids)

    up = core.upload(5)
    assert up is not None and len(up.point_ids) == len(up.keypoints) == len(up.depths)
    observed = {int(i) for i in up.point_ids if i}
    assert observed == {int(i) for i in records[5].track_ids}

    first = records[0].track_ids
    update = _first_frame_mapped(core, records)
    global_ids = update.point_ids
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


def test_a_frame_the_motion_model_loses_is_relocalised_then_tracked_after_probation() -> None:
    """The relocalised pose is right at once, but the device counts itself tracked (and its
    frames uploadable) only after ``reloc_probation_frames`` frames tracked by the motion
    model from it; that first counted frame reports the relocalisation."""
    probation = TrackingConfig().reloc_probation_frames
    seq = SyntheticSequence(12 + probation, seed=0)
    frames = list(seq)
    core = DeviceTrackerCore(seq.intrinsics, 60)
    _track(core, frames[:10])
    wrong = np.eye(4)
    wrong[:3, 3] = [0.6, -0.4, 0.5]           # a motion model 80 cm off: nothing projects near
    core.tracking._velocity = wrong
    on_probation = [core.track(f.color, f.depth, f.stamp) for f in frames[10:10 + probation]]
    assert not any(r.record.tracked or r.relocalised for r in on_probation)
    assert on_probation[0].lost_now and not on_probation[0].refused
    for r, f in zip(on_probation, frames[10:], strict=False):   # posed all along
        truth = np.linalg.inv(frames[0].pose) @ f.pose
        assert np.linalg.norm(r.record.pose[:3, 3] - truth[:3, 3]) < 0.05
    back = core.track(frames[10 + probation].color, frames[10 + probation].depth,
                      frames[10 + probation].stamp)
    assert back.relocalised and back.record.tracked and back.recovered   # what the node logs
    after = core.track(frames[11 + probation].color, frames[11 + probation].depth,
                       frames[11 + probation].stamp)
    assert after.record.tracked and not after.relocalised
    assert not after.recovered and not after.lost_now


def test_the_pose_gate_refuses_a_relocalisation_to_the_wrong_place() -> None:
    """A hand-made wrong match: the map moved 2 m, as if the room had a twin elsewhere — every
    descriptor matches and RANSAC finds a consistent pose with hundreds of inliers, 2 m from
    where the device was lost a frame earlier. The gate refuses it (the device stays lost,
    no probation starts), and a pose solved with too few inliers is refused as well."""
    seq = SyntheticSequence(12, seed=0)
    frames = list(seq)
    core = DeviceTrackerCore(seq.intrinsics, 60)
    _track(core, frames[:10])
    tracking = core.tracking
    tracking.map.positions[:] += np.array([2.0, 0.0, 0.0])
    wrong = np.eye(4)
    wrong[:3, 3] = [0.6, -0.4, 0.5]
    tracking._velocity = wrong
    refused = core.track(frames[10].color, frames[10].depth, frames[10].stamp)
    assert "m from the last tracked pose" in refused.refused, refused.refused
    assert not refused.record.tracked and not refused.relocalised and refused.lost_now
    feats = tracking.extractor.extract(frames[11].color)
    _, _, pose, inliers = tracking.relocalise(feats)
    assert pose is not None and inliers.sum() >= 100        # the wrong place, found well
    config = tracking.config
    assert tracking.gate(pose, config.reloc_min_inliers - 1).startswith(
        f"{config.reloc_min_inliers - 1} inliers")
    assert tracking._last_tracked is not None
    near = tracking._last_tracked.copy()
    near[:3, 3] += [0.2, 0.0, 0.0]
    assert tracking.gate(near, config.reloc_min_inliers) == ""    # within reach: accepted


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
    core = DeviceTrackerCore(seq.intrinsics, SLOT, keep_slots=2, map_source="edge+local")
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


def _update_from_own_points(core: DeviceTrackerCore, version: int, track_ids: np.ndarray,
                            first_global: int = 1) -> MapSnapshot:
    """A map update that turns the device's own points ``track_ids`` into map points at the
    positions the device gave them (what the edge does with uploaded keyframes)."""
    rows = np.array([int(np.flatnonzero(core.labels == t)[0]) for t in track_ids])
    ids = np.arange(first_global, first_global + len(rows), dtype=np.uint64)
    return MapSnapshot(version, np.array([0], np.uint64), np.eye(4)[None], ids,
                       core.tracking.map.positions[rows].copy(),
                       core.tracking.map.descriptors[rows].copy(),
                       np.ones(len(rows), np.uint32), [ids], track_ids, ids)


def _foreign_update(version: int, n: int = 400) -> MapSnapshot:
    """A map of points the camera has never seen: random descriptors in front of it."""
    rng = np.random.default_rng(7)
    ids = np.arange(10_000, 10_000 + n, dtype=np.uint64)
    positions = rng.uniform([-1.0, -0.7, 1.0], [1.0, 0.7, 3.0], (n, 3))
    return MapSnapshot(version, np.array([0], np.uint64), np.eye(4)[None], ids, positions,
                       rng.integers(0, 256, (n, 32), dtype=np.uint8),
                       np.ones(n, np.uint32), [ids])


def test_edge_mode_tracks_only_against_the_map_update_and_makes_no_point() -> None:
    """The paper's device: after the first map update every pose comes from the update's
    points alone — the map it tracks with holds exactly those, however far it tracks — while
    the frame summaries and uploads still carry device-local track ids for the edge."""
    seq = SyntheticSequence(4 * SLOT, seed=0)
    frames = list(seq)
    core = DeviceTrackerCore(seq.intrinsics, SLOT, map_source="edge")
    first = _track(core, frames[:SLOT])
    records = core.take_slot()
    assert all(r.record.tracked for r in first)
    assert all(r.map_version == 0 for r in records), "slot 0 tracks on the start-up map"
    startup = records[0].track_ids
    assert len(core.tracking.map) == len(startup), "only the first frame's depth made points"

    update = _update_from_own_points(core, 1, startup)
    assert core.apply_map_update(update, 0)
    for k in (1, 2, 3):
        results = _track(core, frames[k * SLOT:(k + 1) * SLOT])
        later = core.take_slot()
        assert sorted(core.labels.tolist()) == sorted(update.point_ids.tolist()), \
            "the map the device tracks with holds a point the update did not send"
        assert all(r.record.tracked for r in results), f"slot {k} lost tracking"
        assert all(r.map_version == 1 and r.inliers >= 15 for r in later)
        assert all(len(r.map_point_ids) == r.inliers for r in later)
        # feature tracks for the edge's covisibility: shared between the slot's frames
        assert all(len(r.track_ids) > 0 and all(is_track_id(t) for t in r.track_ids)
                   for r in later)
        assert len(set(later[0].track_ids.tolist()) & set(later[-1].track_ids.tolist())) > 20
    payload = core.upload(3 * SLOT + 2)
    assert payload is not None
    sent = {int(i) for i in payload.point_ids if i}
    record = later[2]
    assert sent == {int(i) for i in record.map_point_ids} | {int(i) for i in record.track_ids}
    truth = np.linalg.inv(frames[0].pose) @ frames[-1].pose
    assert np.linalg.norm(results[-1].record.pose[:3, 3] - truth[:3, 3]) < 0.05


def test_edge_mode_loses_a_frame_that_shares_no_point_with_the_map_update() -> None:
    """The same frames and the same map update of points the camera never saw: the Edge-SLAM
    style device tracks on with its own points, the paper's device loses the frames; a later
    update that holds what the camera sees brings it back by relocalisation."""
    seq = SyntheticSequence(3 * SLOT, seed=2)
    frames = list(seq)
    outcomes = {}
    for source in ("edge", "edge+local"):
        core = DeviceTrackerCore(seq.intrinsics, SLOT, map_source=source)
        _track(core, frames[:SLOT])
        core.take_slot()
        assert core.apply_map_update(_foreign_update(1), 0)      # the answer to slot 0
        outcomes[source] = _track(core, frames[SLOT:SLOT + 5])
        if source == "edge":
            records = [r.record for r in outcomes[source]]
            assert [r.tracked for r in records] == [False] * 5
            assert all(r.inliers == 0 and len(r.map_point_ids) == 0 for r in records)
            assert outcomes[source][0].lost_now
    assert all(r.record.tracked for r in outcomes["edge+local"])

    core = DeviceTrackerCore(seq.intrinsics, SLOT, map_source="edge")
    records = [r.record for r in _track(core, frames[:SLOT])]
    core.take_slot()
    seen = _update_from_own_points(core, 2, records[0].track_ids)   # kept for later
    assert core.apply_map_update(_foreign_update(1), 1)
    lost = _track(core, frames[SLOT:SLOT + 2])
    assert not any(r.record.tracked for r in lost)
    assert core.apply_map_update(seen, 1)
    back = _track(core, frames[SLOT + 2:SLOT + 3])[0]
    assert back.record.tracked and back.recovered and back.record.map_version == 2
    truth = np.linalg.inv(frames[0].pose) @ frames[SLOT + 2].pose
    assert np.linalg.norm(back.record.pose[:3, 3] - truth[:3, 3]) < 0.05


def test_a_paper_device_lost_too_long_tracks_with_its_own_points_until_the_edge_map_holds_them(
) -> None:
    """The paper's device after a map update of points the camera never saw: without
    ``own_map_after`` it stays lost (nothing it sees can be uploaded); with 3 its feature
    tracks — under the ids its summaries already gave the edge — join its map after the third
    lost frame and it tracks on with them: poses near the truth, frames the edge can ask for,
    the log saying so. Once the edge's map holds those points it is the paper's device again,
    tracking with the edge's points alone, the rest of its own points tracks again."""
    seq = SyntheticSequence(3 * SLOT, seed=2)
    frames = list(seq)
    core = DeviceTrackerCore(seq.intrinsics, SLOT, map_source="edge", own_map_after=3)
    _track(core, frames[:SLOT])
    reported = {int(t) for r in core.take_slot() for t in r.track_ids}
    assert core.apply_map_update(_foreign_update(1), 0)
    results = _track(core, frames[SLOT:2 * SLOT])
    assert [r.record.tracked for r in results[:3]] == [False] * 3
    assert [r.own_map for r in results] == ["", "", "", "started"] + [""] * (SLOT - 4)
    assert any("points of its own" in line.text and line.warning
               for line in frame_log_lines(results[3]))
    assert core.own_map and all(r.record.tracked for r in results[3:])
    assert all(core.upload(r.record.frame_id) is not None for r in results[3:])
    for r in results[3:]:
        truth = np.linalg.inv(frames[0].pose) @ frames[r.record.frame_id].pose
        assert np.linalg.norm(r.record.pose[:3, 3] - truth[:3, 3]) < 0.05
    records = core.take_slot()
    own = records[-1].track_ids
    assert len(own) >= 30 and not len(records[-1].map_point_ids)
    assert {int(t) for t in own} & reported, "the tracks the edge knew lost their ids"

    assert core.apply_map_update(_update_from_own_points(core, 2, own), 1)   # uploaded
    back = _track(core, frames[2 * SLOT:2 * SLOT + 3])
    assert all(r.record.tracked and r.record.map_version == 2 for r in back)
    assert back[0].own_map == "ended" and not core.own_map
    assert not is_track(core.labels).any(), "own points stayed in the map"
    assert all(len(r.record.track_ids) for r in back), "no feature tracks for the edge"

    core = DeviceTrackerCore(seq.intrinsics, SLOT, map_source="edge")
    _track(core, frames[:SLOT])
    core.take_slot()
    assert core.apply_map_update(_foreign_update(1), 0)
    assert not any(r.record.tracked for r in _track(core, frames[SLOT:2 * SLOT]))


def test_edge_mode_survives_a_map_update_without_points() -> None:
    """An edge map that holds no point yet (nothing uploaded, or everything evicted): the
    paper's device loses its frames and keeps going, and tracks again on a real map."""
    seq = SyntheticSequence(2 * SLOT, seed=0)
    frames = list(seq)
    core = DeviceTrackerCore(seq.intrinsics, SLOT, map_source="edge")
    records = [r.record for r in _track(core, frames[:SLOT])]
    core.take_slot()
    later = _update_from_own_points(core, 2, records[0].track_ids)
    none = np.zeros(0, np.uint64)
    empty = MapSnapshot(1, none, np.zeros((0, 4, 4)), none, np.zeros((0, 3)),
                        np.zeros((0, 32), np.uint8), np.zeros(0, np.uint32))
    assert core.apply_map_update(empty, 0) and len(core.tracking.map) == 0
    lost = _track(core, frames[SLOT:SLOT + 2])
    assert not any(r.record.tracked for r in lost)
    assert core.upload(SLOT) is not None and not core.upload(SLOT).point_ids.any()
    assert core.apply_map_update(later, 1)
    assert _track(core, frames[SLOT + 2:SLOT + 3])[0].record.tracked


def test_an_unknown_map_source_is_refused_and_a_known_one_applies_at_the_next_frame() -> None:
    seq = SyntheticSequence(2 * SLOT, seed=0)
    frames = list(seq)
    try:
        DeviceTrackerCore(seq.intrinsics, SLOT, map_source="local")
    except ValueError as exc:
        assert "unknown map source 'local'" in str(exc) and "edge+local" in str(exc)
    else:
        raise AssertionError("an unknown map source was accepted")
    core = DeviceTrackerCore(seq.intrinsics, SLOT, map_source="edge+local")
    _track(core, frames[:SLOT])
    records = core.take_slot()
    update = _update_from_own_points(core, 1, records[0].track_ids)
    assert core.apply_map_update(update, 0)
    _track(core, frames[SLOT:SLOT + 3])
    assert is_track(core.labels).any(), "edge+local makes points of its own"
    core.set_map_source("edge")
    assert sorted(core.labels.tolist()) == sorted(update.point_ids.tolist())
    after = _track(core, frames[SLOT + 3:])
    assert all(r.record.tracked for r in after)
    assert sorted(core.labels.tolist()) == sorted(update.point_ids.tolist())


def test_a_lost_device_relocalises_on_every_third_frame_and_at_once_on_a_new_map() -> None:
    """Matching every map point costs several tracked frames: while lost the device tries it
    on the first lost frame and every third after, and again as soon as a new map arrives."""
    seq = SyntheticSequence(SLOT + 1, seed=1)
    frames = list(seq)
    core = DeviceTrackerCore(seq.intrinsics, SLOT, map_source="edge")
    records = [r.record for r in _track(core, frames[:SLOT])]
    core.take_slot()
    attempts: list[int] = []
    search = core.tracking._match_all

    def counted(feats):  # type: ignore[no-untyped-def]
        attempts.append(core.tracking.frames_tracked)
        return search(feats)

    core.tracking._match_all = counted  # type: ignore[method-assign]
    blank = np.zeros_like(frames[0].color)
    for i in range(7):
        assert not core.track(blank, None, frames[SLOT].stamp + i / 30).record.tracked
    assert attempts == [SLOT + 1, SLOT + 4, SLOT + 7]       # lost frames 1, 4 and 7
    assert core.apply_map_update(_update_from_own_points(core, 1, records[0].track_ids), 0)
    core.track(blank, None, frames[SLOT].stamp + 7 / 30)
    assert attempts[-1] == SLOT + 8, "a new map is tried at once"


def test_a_loop_corrected_map_moves_the_devices_own_points_and_pose_with_it() -> None:
    """The edge closed a loop: its update carries the map moved by a correction C (10 cm and
    a degree) and says so (``frame_correction``). The device's own recent points and its
    poses move with it, so it goes on tracking in the corrected frame — each next pose C times
    where it was, no jump the motion gate would refuse — on one map, not on the corrected map
    and its own uncorrected copy of the same walls."""
    seq = SyntheticSequence(3 * SLOT, seed=0)
    frames = list(seq)
    core = DeviceTrackerCore(seq.intrinsics, SLOT, map_source="edge+local")
    _track(core, frames[:SLOT])
    records = core.take_slot()
    _track(core, frames[SLOT:SLOT + 5])           # slot 1 under way when slot 0's map comes
    correction = np.eye(4)
    angle = np.radians(1.0)
    correction[:3, :3] = [[np.cos(angle), -np.sin(angle), 0], [np.sin(angle), np.cos(angle), 0],
                          [0, 0, 1]]
    correction[:3, 3] = (0.1, 0.0, 0.02)
    update = _update_from_own_points(core, 1, records[0].track_ids)
    update.positions = update.positions @ correction[:3, :3].T + correction[:3, 3]
    update.frame_correction = correction
    own = is_track(core.labels)
    resolved = set(records[0].track_ids.tolist())
    active = core.tracking.map.active
    before = {int(label): core.tracking.map.positions[row].copy()
              for row, label in enumerate(core.labels)
              if own[row] and active[row] and int(label) not in resolved}
    assert before, "the device holds no point of its own beside the update's"
    assert core.apply_map_update(update, 0)
    np.testing.assert_array_equal(core.frame_correction, correction)
    rows = {int(label): row for row, label in enumerate(core.labels)}
    for label, xyz in before.items():
        np.testing.assert_allclose(core.tracking.map.positions[rows[label]],
                                   correction[:3, :3] @ xyz + correction[:3, 3], atol=1e-9)
    results = _track(core, frames[SLOT + 5:2 * SLOT])
    assert all(r.record.tracked for r in results), [r.record for r in results]
    for r, frame in zip(results, frames[SLOT + 5:2 * SLOT], strict=True):
        expected = correction @ np.linalg.inv(frames[0].pose) @ frame.pose
        assert np.linalg.norm(r.record.pose[:3, 3] - expected[:3, 3]) < 0.02
    # the same update again changes nothing: the frame is corrected once
    assert not core.apply_map_update(update, 0)


def test_a_map_update_renames_the_labels_it_resolves_and_finds_the_points_it_holds() -> None:
    """The device's labels (map points and its own tracks, uint64) renamed by the tracks the
    edge resolved — a track named twice takes its last name, as the update lists them — and
    the map update's points found among the labels that name map points (a track whose
    counter equals a point id is not that point)."""
    track = as_track_ids(np.array([7, 8, 9]))
    labels = np.array([5, track[0], 6, track[1], 5, track[2]], dtype=np.uint64)
    renamed = relabelled(labels, np.array([track[1], track[0], track[1]]),
                         np.array([40, 41, 42], dtype=np.uint64))
    assert renamed.tolist() == [5, 41, 6, 42, 5, int(track[2])]
    held, rows = rows_of_points(renamed, np.array([5, 9, 42, 6, 100], dtype=np.uint64))
    assert held.tolist() == [True, False, True, True, False]
    assert rows[held].tolist() == [4, 3, 2]              # 5 at its last row
    nothing, _ = rows_of_points(as_track_ids(np.array([1, 2])), np.array([1], np.uint64))
    assert not nothing.any()


def test_a_map_updates_cpu_counts_in_the_next_frames_and_only_there() -> None:
    """The map update runs on the subscription's thread between two frames; its CPU is the
    device's too: the next frame reports it with its own tracking, the one after does not —
    so the frames' ``cpu_ms`` add up to the device's CPU."""
    import threading
    import time

    seq = SyntheticSequence(3 * SLOT, seed=0)
    frames = list(seq)
    core = DeviceTrackerCore(seq.intrinsics, SLOT)
    _track(core, frames[:SLOT])
    core.take_slot()

    def busy_swap(update: MapSnapshot, slot: int) -> None:      # 80 ms of this thread's CPU
        end = time.thread_time() + 0.08
        while time.thread_time() < end:
            pass

    core._swap_in = busy_swap                                   # type: ignore[method-assign]
    update = MapSnapshot(1, np.zeros(0, np.uint64), np.zeros((0, 4, 4)),
                         np.zeros(0, np.uint64), np.zeros((0, 3)), np.zeros((0, 32), np.uint8),
                         np.zeros(0, np.uint32), [], np.zeros(0, np.uint64),
                         np.zeros(0, np.uint64))
    applying = threading.Thread(target=core.apply_map_update, args=(update, 0))
    applying.start()
    applying.join()
    after = [r.record.cpu_ms for r in _track(core, frames[SLOT:SLOT + 3])]
    assert after[0] >= 80.0 and all(ms < 80.0 for ms in after[1:]), after


def test_a_frame_over_its_candidate_cap_searches_the_edges_points_and_its_own_alike() -> None:
    """An Edge-SLAM style device holds the edge's map and the points it made itself since; a
    frame that sees more of them than it may search gives each kind up to half its searches
    (the newest seen of each), either filling what the other leaves. Ranked by sighting alone
    its own points, seen in every frame since they were made, crowded the edge's out — the
    points the edge counts a frame tracked on; the edge's first alone starved its tracking
    where the edge's map disagrees with the camera."""
    seq = SyntheticSequence(4 * SLOT, seed=0)
    frames = list(seq)
    cap = 150
    core = DeviceTrackerCore(seq.intrinsics, SLOT, config=TrackingConfig(max_candidates=cap),
                             map_source="edge+local")
    _track(core, frames[:SLOT])
    records = core.take_slot()
    assert core.apply_map_update(_first_frame_mapped(core, records), 0)
    checked = 0
    for frame in frames[SLOT:]:
        if core.track(frame.color, frame.depth, frame.stamp).slot_done:
            core.take_slot()
        search = core.tracking.last_search
        own_in_view = int(is_track(core.labels[search.in_view]).sum())
        edge_in_view = len(search.in_view) - own_in_view
        if len(search.in_view) <= cap or own_in_view == 0:
            continue
        own_searched = int(is_track(core.labels[search.searched]).sum())
        assert len(search.searched) == cap
        assert cap - own_searched >= min(edge_in_view, cap // 2), (edge_in_view, own_searched)
        assert own_searched >= min(own_in_view, cap // 2), (own_in_view, own_searched)
        checked += 1
    assert checked >= SLOT, "the cap must bite with both kinds of point in view"
    with pytest.raises(ValueError, match="own_share is a share of max_candidates"):
        TrackingConfig(own_share=1.5)


def test_a_frame_searches_no_point_it_sees_from_far_off_where_the_map_saw_it() -> None:
    """The map update's keyframes tell the device where each point was seen from; a frame
    searches only the points it sees within ``max_view_angle_deg`` of that direction
    (ORB-SLAM's 60°: an ORB descriptor does not match across a wider turn). The same points
    seen by a keyframe on their far side are left out of the search and told apart
    (``last_search.turned``); at 180° nothing is, and the update's directions are not
    worked out."""
    seq = SyntheticSequence(2 * SLOT, seed=0)
    frames = list(seq)
    searched: dict[tuple[bool, float], tuple[int, int]] = {}
    for behind, angle in ((False, 60.0), (True, 60.0), (True, 180.0)):
        core = DeviceTrackerCore(seq.intrinsics, SLOT,
                                 config=TrackingConfig(max_view_angle_deg=angle),
                                 map_source="edge")
        _track(core, frames[:SLOT])
        update = _first_frame_mapped(core, core.take_slot())
        if behind:                       # the keyframe stood beyond the points, facing back
            pose = np.eye(4)
            pose[:3, 3] = 2.0 * update.positions.mean(axis=0)
            update = dataclasses.replace(update, keyframe_poses=pose[None])
        assert core.apply_map_update(update, 0)
        core.track(frames[SLOT].color, frames[SLOT].depth, frames[SLOT].stamp)
        search = core.tracking.last_search
        edge = ~is_track(core.labels)
        searched[behind, angle] = (int(edge[search.searched].sum()),
                                   int(edge[search.turned].sum()))
        # the update's directions are worked out only where the search reads them
        known = ~np.isnan(core.tracking.map.views[edge]).any(axis=1)
        assert known.all() if angle < 180.0 else not known.any(), (behind, angle)
    assert searched[False, 60.0][0] > 100 and searched[False, 60.0][1] == 0, searched
    assert searched[True, 60.0] == (0, searched[False, 60.0][0]), searched
    assert searched[True, 180.0] == (searched[False, 60.0][0], 0), searched
    with pytest.raises(ValueError, match="max_view_angle_deg"):
        TrackingConfig(max_view_angle_deg=0.0)
