"""Two devices' maps of one place merged into one frame: the second device's keyframes found
in the first device's map give the rigid motion between their frames, confirmed by later
keyframes before the second map moves; a look-alike place is not merged; the moved map —
keyframes, archive, points and the frame its device is told — is the first map's frame; the
edge merges a later device into an earlier one's frame, beside the slots, whichever of the two
finds the other."""

from __future__ import annotations

import dataclasses
import os
import threading
import time
from concurrent.futures import Future
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from edge_mapper.edge_core import EdgeConfig, EdgeMapperCore, set_aside
from edge_mapper.place_membership import PlaceMembership, source_of
from edge_mapper.place_merging import MergeEvent, PlaceMerging, _look
from edge_mapper.slot_planner import FrameObservations, SlotConfig
from tests.test_archive_relocalisation import room  # noqa: F401 (the archived room fixture)
from tests.test_keyframe_database import places  # noqa: F401 (the room's and corridor's features)
from twinslam.policies.registry import make_policy
from twinslam.rotations import rotation_angle_deg
from twinslam.slam.back_end.foreign_keyframes import foreign_tag, is_foreign, ties_to_copies
from twinslam.slam.back_end.keyframe_archive import ArchivedKeyFrame, KeyFrameArchive, restore_into
from twinslam.slam.back_end.keyframe_database import KeyFrameDatabase, WeightedWords
from twinslam.slam.back_end.keyframe_map import KeyFrameMap
from twinslam.slam.back_end.loop_closing import (
    ACROSS_GAP_SLOTS,
    ACROSS_NEAR_M,
    LoopJob,
    LoopQuery,
    SharedWorker,
    run_job,
)
from twinslam.slam.back_end.loop_correction import correct_map, correction_for
from twinslam.slam.back_end.map_back_end import (
    APPLIED_LOOPS_KEPT,
    AppliedLoop,
    BackEndConfig,
    MapBackEnd,
    archive_folder,
)
from twinslam.slam.back_end.map_merging import (
    Lender,
    MergeFinder,
    follow_lender_loops,
    lend_from,
    welded,
)
from twinslam.slam.back_end.view_coverage import CoverageBounds
from twinslam.slam.camera import Camera
from twinslam.slam.front_end.orb_extractor import OrbExtractor
from twinslam.slam.front_end.tracking import depth_at
from twinslam.slam.keyframe import KeyFramePayload
from twinslam.thread_priority import PER_THREAD_NICE

Room = tuple[object, KeyFrameArchive, OrbExtractor]

#: the second device's map frame in the first's: its first camera 2 m away, turned 100°
SECOND_IN_FIRST = np.eye(4)
_a = np.radians(100.0)
SECOND_IN_FIRST[:3, :3] = [[np.cos(_a), 0, np.sin(_a)], [0, 1, 0], [-np.sin(_a), 0, np.cos(_a)]]
SECOND_IN_FIRST[:3, 3] = [2.0, 0.1, -1.0]


def _query(room: Room, frame_index: int, keyframe: int) -> LoopQuery:  # noqa: F811
    """The room's frame ``frame_index`` as the second device's keyframe ``keyframe``."""
    seq, _, orb = room
    frame = seq.read(frame_index)                              # type: ignore[attr-defined]
    feats = orb.extract(frame.color)
    return LoopQuery(keyframe, feats.points, feats.descriptors,
                     depth_at(feats.points, frame.depth, (0.2, 8.0)))


def _second_pose(room: Room, frame_index: int, shift_m: float = 0.0) -> np.ndarray:  # noqa: F811
    """Where the second device's own map has the room's frame ``frame_index`` (its true pose
    in the second frame), moved ``shift_m`` along that frame's x."""
    pose = np.linalg.inv(SECOND_IN_FIRST) @ room[0].read(frame_index).pose  # type: ignore[attr-defined]
    pose[0, 3] += shift_m
    return pose


def test_a_second_map_is_merged_where_three_keyframes_find_the_first(room: Room) -> None:  # noqa: F811
    """The second device sees the first device's room from frames 4, 64 and 124: the first
    finding proposes the merge, the next two confirm it; the alignment is the true motion
    between the two maps' frames to within centimetres and a fraction of a degree."""
    _, archive, _ = room
    finder = MergeFinder()
    frames = {10: 4, 11: 64, 12: 124}                  # the second device's keyframe ids
    poses = {k: _second_pose(room, f) for k, f in frames.items()}
    merges = [finder.offer(archive, _query(room, f, k), poses, room[0].intrinsics)  # type: ignore[attr-defined]
              for k, f in frames.items()]
    assert merges[0] is None and merges[1] is None     # found, not yet confirmed
    merge = merges[2]
    assert merge is not None and merge.joining == 12 and merge.inliers >= 50
    assert finder.candidates == 3
    off = np.linalg.inv(SECOND_IN_FIRST) @ merge.alignment
    assert np.linalg.norm(off[:3, 3]) < 0.03 and rotation_angle_deg(off[:3, :3]) < 0.5


def test_a_merge_waits_for_detections_with_the_inliers_its_gate_asks(room: Room) -> None:  # noqa: F811
    """The same three views with a merge gate above what their geometry finds (the edge's
    ``merge_min_inliers``): none counts as a detection, no merge, and why is said; at a gate
    the views clear, the merge comes as before."""
    _, archive, _ = room
    frames = {10: 4, 11: 64, 12: 124}
    poses = {k: _second_pose(room, f) for k, f in frames.items()}
    k = room[0].intrinsics                                      # type: ignore[attr-defined]
    found = MergeFinder()
    inliers = []
    for key, f in frames.items():
        found.offer(archive, _query(room, f, key), poses, k)
        assert found.last is not None and found.last.found
        inliers.append(found.last.inliers)
    strict = MergeFinder(min_inliers=max(inliers) + 1)
    assert all(strict.offer(archive, _query(room, f, key), poses, k) is None
               for key, f in frames.items())
    assert strict.candidates == 0 and strict.last is not None
    assert f"fewer than the merge's {max(inliers) + 1}" in strict.last.reason
    enough = MergeFinder(min_inliers=min(inliers))
    assert [enough.offer(archive, _query(room, f, key), poses, k) is not None
            for key, f in frames.items()] == [False, False, True]


def test_a_look_alike_place_is_not_merged(room: Room) -> None:  # noqa: F811
    """The second device sees what the first mapped — a hotel's identical rooms — but its own
    walk puts the second and third views 1 m and 2 m from where the first view's alignment
    puts them: no two findings agree on one frame, and the maps stay apart. The same views
    at their true poses merge (the control)."""
    _, archive, _ = room
    k = room[0].intrinsics                                      # type: ignore[attr-defined]
    frames = {10: 4, 11: 64, 12: 124, 13: 184}
    finder = MergeFinder()
    shifted = {key: _second_pose(room, f, 1.0 * i) for i, (key, f) in enumerate(frames.items())}
    assert all(finder.offer(archive, _query(room, f, key), shifted, k) is None
               for key, f in frames.items())
    assert finder.candidates == 4 and finder.confirmation.dropped >= 1
    control = MergeFinder()
    true = {key: _second_pose(room, f) for key, f in frames.items()}
    assert [control.offer(archive, _query(room, f, key), true, k) is not None
            for key, f in list(frames.items())[:3]] == [False, False, True]


def _core(vmax: int = 4, checkpoint: Path | None = None) -> EdgeMapperCore:
    k = np.array([[500.0, 0.0, 320.0], [0.0, 500.0, 240.0], [0.0, 0.0, 1.0]])
    return EdgeMapperCore(make_policy("lff"), k, EdgeConfig(
        slot=SlotConfig(vmax=vmax), back_end=BackEndConfig(loop_background=False)),
        checkpoint)


def test_a_merged_map_moves_whole_into_the_place_frame_and_tells_its_device() -> None:
    """Aligning an edge map moves its managed keyframes, its archived keyframes and its points
    by the merge's motion; the next map version is in the new frame (its frame correction),
    and a keyframe the device posed on the map before arrives in the new frame too."""
    core = _core()
    rng = np.random.default_rng(4)
    for kf in range(3):
        pose = np.eye(4)
        pose[:3, 3] = [0.2 * kf, 0.0, 0.0]
        core.map.add_keyframe(kf, pose)
    for _ in range(30):
        xyz = rng.uniform(-1, 1, 3) + np.array([0.0, 0.0, 3.0])
        pid = core.map.add_point(xyz, np.zeros(32, np.uint8))
        for kf in range(3):
            core.map.observe(kf, pid, (320.0, 240.0), 3.0)
    core.back_end.evict_to_archive([0], slot=0)
    before_map = {k: kf.pose.copy() for k, kf in core.map.keyframes.items()}
    before_archive = {kf.id: kf.pose.copy() for kf in core.archive}
    before_points = {p: pt.position.copy() for p, pt in core.map.points.items()}
    version = core.version
    core.align(SECOND_IN_FIRST)
    for k, pose in before_map.items():
        np.testing.assert_allclose(core.map.keyframes[k].pose, SECOND_IN_FIRST @ pose)
    for archived in core.archive:
        np.testing.assert_allclose(archived.pose, SECOND_IN_FIRST @ before_archive[archived.id])
    for p, xyz in before_points.items():
        np.testing.assert_allclose(core.map.points[p].position,
                                   SECOND_IN_FIRST[:3, :3] @ xyz + SECOND_IN_FIRST[:3, 3])
    np.testing.assert_allclose(core.frame_correction, SECOND_IN_FIRST)
    np.testing.assert_allclose(core.frame_correction_at(version + 1), SECOND_IN_FIRST)
    np.testing.assert_allclose(core.frame_correction_at(version), np.eye(4))
    posed = np.eye(4)
    posed[:3, 3] = [0.6, 0.0, 0.0]
    upload = KeyFramePayload(frame_id=40, slot=1, pose=posed, intrinsics=core.k,
                             keypoints=np.zeros((0, 2)), descriptors=np.zeros((0, 32), np.uint8),
                             depths=np.zeros(0), point_ids=np.zeros(0, np.uint64), stamp=1.0)
    moved = core.back_end.device.in_current_frame(upload, version)
    np.testing.assert_allclose(moved.pose, SECOND_IN_FIRST @ posed)


def _payload(room: Room, frame_index: int, keyframe: int) -> KeyFramePayload:  # noqa: F811
    """The room's frame as the second device uploads it (its features; no point ids)."""
    query = _query(room, frame_index, keyframe)
    assert query.depths is not None
    n = len(query.points_xy)
    return KeyFramePayload(frame_id=keyframe, slot=0, stamp=float(keyframe),
                           pose=_second_pose(room, frame_index),
                           intrinsics=room[0].intrinsics,      # type: ignore[attr-defined]
                           keypoints=query.points_xy, depths=query.depths,
                           descriptors=query.descriptors, point_ids=np.zeros(n, np.uint64))


def _room_and_newcomer(room: Room, folder: Path | None = None  # noqa: F811
                       ) -> dict[str, EdgeMapperCore]:
    """ar1's map of the room (its archive and keyframe 999), and ar2's, empty yet; with
    ``folder``, each core checkpoints there."""
    _, archive, _ = room
    cores = {name: _core(checkpoint=folder / f"edge.{name}.npz" if folder else None)
             for name in ("ar1", "ar2")}
    for kf in archive:                                 # the first device's map of the room
        cores["ar1"].archive.add(kf)
    cores["ar1"].map.add_keyframe(999, archive.get(270).pose)
    for core in cores.values():
        core.back_end.device.k = room[0].intrinsics                    # type: ignore[attr-defined]
    return cores


def _walk_ar2_into_the_room(room: Room, cores: dict[str, EdgeMapperCore],  # noqa: F811
                            merging: PlaceMerging) -> list[MergeEvent | None]:
    """ar2's keyframes 10, 11 and 12 (the room's frames 4, 64, 124), one a slot, each
    looked for after its slot; what each slot end took, and the one after."""
    events = []
    for slot, (key, frame) in enumerate(((10, 4), (11, 64), (12, 124))):
        cores["ar2"].map.add_keyframe(key, _second_pose(room, frame))
        merging.keyframe("ar2", _payload(room, frame, key))
        events.append(merging.take("ar2"))             # the slot end takes the last look
        merging.look("ar2", slot)
        merging.look("ar1", slot)                      # nothing: no keyframes of its own
    events.append(merging.take("ar2"))
    return events


def test_the_edge_merges_a_later_device_into_an_earlier_ones_frame(room: Room) -> None:  # noqa: F811
    """The edge's merging over its devices' cores: the second device's keyframes, looked for
    after its slots, join the first device's frame at the slot end after the third; the
    first device has no keyframes of its own to look for, and a device that joined looks no
    more."""
    _, archive, _ = room
    cores = _room_and_newcomer(room)
    merging = PlaceMerging(lambda: cores, background=False)
    assert merging.others("ar1") == ["ar2"] and merging.others("ar2") == ["ar1"]
    events = _walk_ar2_into_the_room(room, cores, merging)
    assert events[:3] == [None, None, None] and events[3] is not None
    assert events[3].place == "ar1" and merging.joined == {"ar2": "ar1"}
    off = np.linalg.inv(SECOND_IN_FIRST) @ cores["ar2"].frame_correction
    assert np.linalg.norm(off[:3, 3]) < 0.03 and rotation_angle_deg(off[:3, :3]) < 0.5
    np.testing.assert_allclose(cores["ar2"].map.keyframes[12].pose,
                               events[3].merge.alignment @ _second_pose(room, 124))
    assert merging.others("ar2") == [] and merging.others("ar1") == []
    assert len(merging.look_ms) == 3 and not merging.failures()
    # the place's devices recognise places under one vocabulary: the root's
    assert cores["ar2"].archive.words.source() is cores["ar1"].archive.words
    assert cores["ar1"].archive.words.source() is cores["ar1"].archive.words
    # from then on each map adopts the other's own keyframes, each once, tagged by lender
    assert merging.before_slot_end("ar2", 4) == (None, len(archive) + 1, [])
    assert merging.before_slot_end("ar2", 5) == (None, 0, [])
    adopted = sorted(kf.id for kf in cores["ar2"].archive)
    ar1, ar2 = foreign_tag(source_of("ar1")), foreign_tag(source_of("ar2"))
    assert adopted == sorted(ar1 | k for k in [*(kf.id for kf in archive), 999])
    assert merging.before_slot_end("ar1", 4) == (None, 3, [])  # ar2's keyframes 10, 11, 12
    assert sorted(cores["ar1"].archive.get(ar2 | k).id & 0xFFFF
                  for k in (10, 11, 12)) == [10, 11, 12]
    assert merging.lend_all("ar1", ["ar2"], 6)[0].adopted == 0  # never those it lent back
    # each map's loops may close with the keyframes it borrowed from the other
    assert cores["ar2"].back_end.loop_across == {ar1}
    assert cores["ar1"].back_end.loop_across == {ar2}


def test_paused_looks_start_none_and_resumed_the_newest_keyframes_merge(
        room: Room) -> None:  # noqa: F811
    """An edge over its compute budget pauses the looks (``looking`` off): the second
    device's keyframes start no look and nothing merges however many slots end; once the
    looks resume, its newest keyframes look and join the first device's frame as they would
    have."""
    cores = _room_and_newcomer(room)
    merging = PlaceMerging(lambda: cores, background=False)
    merging.looking = False
    assert _walk_ar2_into_the_room(room, cores, merging) == [None] * 4
    assert merging.look_ms == [] and merging.joined == {}
    merging.looking = True
    merging.look("ar2", 3)
    event = merging.take("ar2")
    assert event is not None and event.place == "ar1" and merging.joined == {"ar2": "ar1"}
    assert len(merging.look_ms) == 1


#: words of the database that ranks the looks: which map a look goes to is under test, not
#: how well the default vocabulary (1024 words, tested in test_keyframe_database.py) tells
#: places apart. 512 words learn from the 10 000 descriptors in a third of its k-means time
#: and keep the ranking clear: the corridor's map scores at most 0.70 of the room's (1024
#: words: 0.56) where the share a candidate needs is 0.9; at 256 words it came within 3 % of
#: that share, which another CPU's ORB descriptors could cross
RANKING_WORDS = 512


def _looks_of_ar2_in_the_room(room: Room, places: dict[str, dict[int, np.ndarray]],  # noqa: F811
                              database: KeyFrameDatabase, monkeypatch: pytest.MonkeyPatch,
                              frames: tuple[int, ...] = (4, 64, 124, 184, 244),
                              ar0_uploads: list[np.ndarray] | None = None
                              ) -> tuple[list[str], PlaceMerging]:
    """ar0 mapped the corridor and ar1 the room (their uploads filed in ``database``; with
    ``ar0_uploads`` the database is told ar0 uploaded those descriptors instead — the very
    frames ar2 will, its ranking misjudging where the room is); ar2 walks the room, a
    keyframe a slot (the room's ``frames``), each looked for after its slot; the maps its
    looks went to, in order, until it merged."""
    import edge_mapper.place_merging as place_merging

    cores = {"ar0": _core(), **_room_and_newcomer(room)}
    cores["ar0"].map.add_keyframe(1, np.eye(4))
    cores["ar0"].back_end.device.k = room[0].intrinsics                  # type: ignore[attr-defined]
    uploads = ar0_uploads if ar0_uploads is not None else list(places["corridor"].values())
    for index, descriptors in enumerate(uploads):
        database.add("ar0", index, descriptors)
    for kf in room[1]:
        database.add("ar1", kf.id, kf.descriptors)
    merging = PlaceMerging(lambda: cores, background=False, database=database)
    looked: list[str] = []

    def spied(place: str, *args: object, **kwargs: object) -> object:
        looked.append(place)
        return _look(place, *args, **kwargs)                      # type: ignore[arg-type]

    monkeypatch.setattr(place_merging, "_look", spied)
    for slot, frame in enumerate(frames):
        key = 10 + slot
        cores["ar2"].map.add_keyframe(key, _second_pose(room, frame))
        merging.keyframe("ar2", _payload(room, frame, key))
        merging.take("ar2")
        merging.look("ar2", slot)
    merging.take("ar2")
    return looked, merging


def test_a_look_goes_to_the_map_its_keyframes_scored_highest_in(
        room: Room, places: dict[str, dict[int, np.ndarray]],  # noqa: F811
        monkeypatch: pytest.MonkeyPatch) -> None:
    """The first look has nothing ranked and takes the other maps in turn (the corridor's);
    it scores ar2's keyframes in the keyframe database, and the next looks go to the room's
    map, where three of them merge ar2. Taken in turn, every other look went to the corridor
    and five slots were not enough."""
    ranked = KeyFrameDatabase(learn_from=10_000, words=RANKING_WORDS)
    looked, merging = _looks_of_ar2_in_the_room(room, places, ranked, monkeypatch)
    assert looked == ["ar0", "ar1", "ar1", "ar1"] and merging.joined == {"ar2": "ar1"}
    # the edge's log of the first, unmerged look says where the next ones go, and why
    assert merging.unmerged_looks["ar2"][1].endswith(
        "; the next in ar1's map, whose keyframes its own are most like")
    in_turn, unmerged = _looks_of_ar2_in_the_room(room, places,
                                                  KeyFrameDatabase(learn_from=10**9),
                                                  monkeypatch)
    assert in_turn == ["ar0", "ar1", "ar0", "ar1", "ar0"] and unmerged.joined == {}
    assert unmerged.unmerged_looks["ar2"][1].endswith(
        "the next in the other maps in turn (no ranking: the keyframe database has no words "
        "yet)")


def test_a_device_whose_looks_find_nothing_looks_less_often_until_a_new_map_is_served(
        room: Room, monkeypatch: pytest.MonkeyPatch) -> None:  # noqa: F811
    """With a backoff of 4 slots, ar2's looks into a map of another place (ar0's, which
    holds nothing of the room) come twice as far apart after each that found no candidate:
    at slots 0, 2 and 6, not every slot. Once the edge serves ar1, whose map is the room, ar2
    looks at once — a map it never looked among — and merges as it would have; the default
    (1) looks after every slot."""
    import edge_mapper.place_merging as place_merging

    def walk(backoff: int) -> tuple[list[int], PlaceMerging]:
        newcomer = _room_and_newcomer(room)
        cores = {"ar0": _core(), "ar2": newcomer["ar2"]}
        cores["ar0"].map.add_keyframe(1, np.eye(4))
        cores["ar0"].back_end.device.k = room[0].intrinsics              # type: ignore[attr-defined]
        merging = PlaceMerging(lambda: cores, background=False, look_backoff_slots=backoff)
        looked_at: list[int] = []
        slot = 0

        def spied(place: str, *args: object, **kwargs: object) -> object:
            looked_at.append(slot)
            return _look(place, *args, **kwargs)                  # type: ignore[arg-type]

        monkeypatch.setattr(place_merging, "_look", spied)
        for slot in range(16):
            if slot == 8:
                cores["ar1"] = newcomer["ar1"]                    # the room's map, served now
            frame = 4 + 30 * (slot % 8)
            cores["ar2"].map.add_keyframe(10 + slot, _second_pose(room, frame))
            merging.keyframe("ar2", _payload(room, frame, 10 + slot))
            merging.take("ar2")
            if merging.joined:
                break
            merging.look("ar2", slot)
        return looked_at, merging

    looked_at, merging = walk(backoff=4)
    assert looked_at[:3] == [0, 2, 6] and looked_at[3] == 8
    assert set(merging.joined.items()) in ({("ar2", "ar1")}, {("ar1", "ar2")})
    every_slot, merged = walk(backoff=1)
    assert every_slot[:9] == list(range(9)) and merged.joined == merging.joined
    with pytest.raises(ValueError, match="1 slot or more"):
        PlaceMerging(dict, look_backoff_slots=0)


def test_a_device_alone_files_its_uploads_though_it_makes_no_look(room: Room) -> None:  # noqa: F811
    """One device on an edge that merges maps has no other map to look in, so no look files
    the keyframe database's queue: past FILE_QUEUED uploads the device's slot end has it
    filed (on the worker; here in the caller), and the queue keeps no upload's features."""
    from edge_mapper.place_merging import FILE_QUEUED

    cores = {"ar1": _core()}
    merging = PlaceMerging(lambda: cores, background=False,
                           database=KeyFrameDatabase(learn_from=10**9))
    payload = _payload(room, 4, 10)
    for key in range(FILE_QUEUED - 1):
        merging.keyframe("ar1", dataclasses.replace(payload, frame_id=key))
        merging.look("ar1", key)
    assert merging.database.queued() == FILE_QUEUED - 1       # short: left for a look
    merging.keyframe("ar1", dataclasses.replace(payload, frame_id=FILE_QUEUED))
    merging.look("ar1", FILE_QUEUED)
    assert merging.database.queued() == 0 and merging.look_ms == []


def test_a_device_alone_has_the_words_learned_before_another_device_looks(
        room: Room) -> None:  # noqa: F811
    """Once the uploads queued hold enough descriptors to learn the keyframe database's words
    from, the slot end of a device with no other map to look in has them learned (on a
    thread of their own; here in the caller) and the queue filed, though fewer than
    FILE_QUEUED wait: the first look of a device that comes to its place then ranks with
    words learned, not learning them."""
    from edge_mapper.place_merging import FILE_QUEUED

    payload = _payload(room, 4, 10)
    per_upload = len(payload.descriptors)
    cores = {"ar1": _core()}
    merging = PlaceMerging(lambda: cores, background=False,
                           database=KeyFrameDatabase(learn_from=5 * per_upload))
    for key in range(4):
        merging.keyframe("ar1", dataclasses.replace(payload, frame_id=key))
        merging.look("ar1", key)
    assert merging.database.words is None and merging.database.queued() == 4
    merging.keyframe("ar1", dataclasses.replace(payload, frame_id=4))
    merging.look("ar1", 4)
    assert 5 < FILE_QUEUED
    assert merging.database.words is not None and merging.database.queued() == 0
    assert merging.database.keyframes("ar1") == 5


def _learning_after_three(room: Room  # noqa: F811
                          ) -> tuple[list[KeyFramePayload], PlaceMerging]:
    """Three uploads of the room and one device's merging whose keyframe database learns its
    words once all three came (from their descriptors)."""
    uploads = [_payload(room, 4 + 10 * k, k) for k in range(3)]
    cores = {"ar1": _core()}
    return uploads, PlaceMerging(lambda: cores, database=KeyFrameDatabase(
        learn_from=sum(len(u.descriptors) for u in uploads)))


def test_the_edge_learns_the_words_on_a_thread_of_their_own(
        room: Room, monkeypatch: pytest.MonkeyPatch) -> None:  # noqa: F811
    """With the looks on the worker, a look's ranking never learns the words (it held the
    look, and a merge, up by seconds): once enough descriptors wait, a device's slot end
    starts their learning on a thread of its own, at the lowest priority (Linux: the slots'
    threads keep the cores), and the next ranking takes them."""
    learn, priorities, names = WeightedWords.learn, [], []

    def learn_seen(*args: Any, **kwargs: Any) -> WeightedWords:
        if PER_THREAD_NICE:
            priorities.append(os.getpriority(os.PRIO_PROCESS, threading.get_native_id()))
            # top -H and ps -L show the learning by its name, not the process's
            names.append(Path(f"/proc/self/task/{threading.get_native_id()}/comm")
                         .read_text().strip())
        return learn(*args, **kwargs)

    monkeypatch.setattr(WeightedWords, "learn", learn_seen)
    uploads, merging = _learning_after_three(room)
    try:
        for upload in uploads[:2]:
            merging.keyframe("ar1", upload)
            merging.look("ar1", upload.frame_id)
        assert merging.database.candidates_of("ar1", [1], ["ar1"]) == []
        assert merging.database.words is None and merging._learning is None
        merging.keyframe("ar1", uploads[2])
        merging.look("ar1", 2)
        learning = merging._learning
        assert learning is not None
        learning.join(timeout=60)
        assert not learning.is_alive() and merging.failures() == []
        assert merging.database.candidates_of("ar1", [2], ["ar1"]) == ["ar1"]
        assert merging.database.keyframes("ar1") == 3
        assert priorities == ([19] if PER_THREAD_NICE else [])
        assert names == (["place-words"] if PER_THREAD_NICE else [])
    finally:
        merging.close()


def test_closing_does_not_wait_for_the_words_learning(
        room: Room, monkeypatch: pytest.MonkeyPatch) -> None:  # noqa: F811
    """An edge that stops (SIGTERM) closes its merging at once, whatever the words' learning
    is doing: at the lowest priority on a host its slots and others fill, the learning got so
    little of a core that the edge's shutdown, waiting for it, outlasted the 5 s a stopping
    node is given (a clean clone run beside a CPU hog). Words nobody will score with are
    left to the process's exit."""
    release = threading.Event()

    def learn_slowly(*args: Any, **kwargs: Any) -> WeightedWords:
        release.wait(60.0)
        raise RuntimeError("never offered")

    monkeypatch.setattr(WeightedWords, "learn", learn_slowly)
    uploads, merging = _learning_after_three(room)
    try:
        for k, upload in enumerate(uploads):
            merging.keyframe("ar1", upload)
            merging.look("ar1", k)
        learning = merging._learning
        assert learning is not None and learning.is_alive()
        started = time.monotonic()
        merging.close()
        assert time.monotonic() - started < 5.0
        assert learning.is_alive() and learning.daemon       # the process's exit ends it
    finally:
        release.set()
        merging.close()


def test_a_place_the_words_misjudge_is_still_looked_for_every_eighth_look(
        room: Room, places: dict[str, dict[int, np.ndarray]],  # noqa: F811
        monkeypatch: pytest.MonkeyPatch) -> None:
    """The database ranks ar0's map first for the room though ar0 holds none of it (its
    filed keyframes are ar2's own views, its map a bare keyframe): the ranked looks go
    there in vain, and every EXPLORE_EVERY-th look takes the other maps in turn — the
    room's map among them."""
    from edge_mapper.place_merging import EXPLORE_EVERY

    frames = tuple(range(4, 4 + 30 * (EXPLORE_EVERY + 1), 30))
    # the first-ranked map alone is a candidate: ar0's rows hold ar2's views among three
    # others each and score 0.67-0.84, the room's map 0.53-0.73 — once within the default
    # share (0.91 of ar0's), which made the room's map a candidate too and left ar0's looks
    # to the turn's parity
    misjudging = KeyFrameDatabase(learn_from=10_000, share=1.0)
    looked, _ = _looks_of_ar2_in_the_room(
        room, places, misjudging, monkeypatch, frames=frames,
        ar0_uploads=[_query(room, frame, 0).descriptors for frame in frames])
    assert looked[0] == "ar0" and looked[1:EXPLORE_EVERY - 1] == ["ar0"] * (EXPLORE_EVERY - 2)
    assert looked[EXPLORE_EVERY - 1] == "ar1"                   # the odd look out, in turn


def _started(work: Future[Any]) -> bool:
    """Whether ``work`` had started (or ended) when this ran."""
    return work.running() or work.done()


def test_the_merge_looks_queue_on_the_loop_workers_thread_behind_its_work(
        room: Room) -> None:  # noqa: F811
    """A look goes on the worker the edge's loop jobs run on, behind what is queued there (the
    process's background work is one queue under the loop worker's bounds) and behind a loop
    job queued after it, which goes first; its merge is the one the look in the caller
    makes."""
    worker = SharedWorker()
    release = threading.Event()
    cores = _room_and_newcomer(room)
    merging = PlaceMerging(lambda: cores, worker=worker)
    events: list[MergeEvent | None] = []

    def taken(looks: int) -> None:
        """The slot ends take answers until ``looks`` looks were taken (60 s at most)."""
        deadline = time.monotonic() + 60
        while len(merging.look_ms) < looks and time.monotonic() < deadline:
            events.append(merging.take("ar2"))
            time.sleep(0.01)
        assert len(merging.look_ms) == looks

    try:
        held = worker.submit(release.wait, 60.0)         # a loop job that takes its time
        for slot, (key, frame) in enumerate(((10, 4), (11, 64), (12, 124))):
            cores["ar2"].map.add_keyframe(key, _second_pose(room, frame))
            merging.keyframe("ar2", _payload(room, frame, key))
            merging.look("ar2", slot)
            if slot == 0:
                assert merging.take("ar2") is None and merging.look_ms == []  # behind it
                queued_look = merging._running["ar2"]
                # a loop job of another device, queued after the look, runs before it
                loop = worker.submit(_started, queued_look)
                release.set()
                assert held.result(timeout=60)
                assert loop.result(timeout=60) is False
            taken(slot + 1)
    finally:
        release.set()
        merging.close()
        worker.stop()
    assert [e.place for e in events if e is not None] == ["ar1"]
    assert merging.joined == {"ar2": "ar1"} and not merging.failures()
    off = np.linalg.inv(SECOND_IN_FIRST) @ cores["ar2"].frame_correction
    assert np.linalg.norm(off[:3, 3]) < 0.03 and rotation_angle_deg(off[:3, :3]) < 0.5


def test_a_look_pauses_for_the_slots_before_each_of_its_keyframes(
        room: Room, monkeypatch: pytest.MonkeyPatch) -> None:  # noqa: F811
    """The worker waits for the slots' work before each keyframe a look offers (as a loop job
    does before each query) and before it ranks them, not once a look; the pauses are not the
    look's time: on a clock that moves only while the look pauses, the look took no time at
    all."""
    import edge_mapper.place_merging as place_merging

    _, archive, _ = room
    frames = {10: 4, 11: 64, 12: 124}
    poses = {k: _second_pose(room, f) for k, f in frames.items()}
    queries = tuple(_query(room, f, k) for k, f in frames.items())
    clock = [0.0]

    def pause() -> None:
        clock[0] += 100.0                                # a long wait for the slots

    monkeypatch.setattr(place_merging.time, "perf_counter", lambda: clock[0])
    look = _look("ar1", MergeFinder(), archive, queries, poses,
                 room[0].intrinsics, np.eye(4), np.eye(4), pause)  # type: ignore[attr-defined]
    assert look.merge is not None and look.merge.joining == 12 and not look.error
    # a pause before the keyframe database's ranking and one before each keyframe, none of
    # them counted
    assert clock[0] == 400.0 and look.ms == 0.0


def test_a_look_whose_ranking_fails_still_searches_and_says_why(room: Room) -> None:  # noqa: F811
    """The keyframe database failing to rank (a faiss error, say) costs the next look its
    choice of map, not this look its search: it merges as it would have, the failure in its
    answer for the slot end to log, and nothing ranked for the next one."""
    _, archive, _ = room
    frames = {10: 4, 11: 64, 12: 124}
    poses = {k: _second_pose(room, f) for k, f in frames.items()}
    queries = tuple(_query(room, f, k) for k, f in frames.items())

    def broken() -> list[str]:
        raise RuntimeError("no words")

    look = _look("ar1", MergeFinder(), archive, queries, poses,
                 room[0].intrinsics, np.eye(4), np.eye(4),     # type: ignore[attr-defined]
                 rank=broken)
    assert look.merge is not None and look.merge.joining == 12
    assert look.error == "ranking the maps: RuntimeError: no words" and look.ranked == ()


def test_a_look_whose_ranking_and_search_both_fail_says_both(room: Room) -> None:  # noqa: F811
    """A look whose search raised after its ranking failed reports the two failures, the
    search's first: the slot end logs one line, and neither cause is lost."""
    _, archive, _ = room
    queries = (_query(room, 4, 10),)

    class Failing(MergeFinder):
        def offer(self, *args: object, **kwargs: object) -> None:
            raise ValueError("a broken archive")

    def broken() -> list[str]:
        raise RuntimeError("no words")

    look = _look("ar1", Failing(), archive, queries, {10: _second_pose(room, 4)},
                 room[0].intrinsics, np.eye(4), np.eye(4),     # type: ignore[attr-defined]
                 rank=broken)
    assert look.merge is None
    assert look.error == ("ValueError: a broken archive; ranking the maps: RuntimeError: "
                          "no words")


def _tracked_at(core: EdgeMapperCore, slot: int, pose: np.ndarray | None) -> None:
    """``core``'s device summarises a slot whose one frame it tracked at ``pose`` (None: it
    tracked nothing, it is lost), and the edge plans the slot."""
    frame = FrameObservations(1000 + slot, frozenset(), tracked=pose is not None, pose=pose)
    core.plan(slot, [frame], 20.0, 0)


def test_a_keyframe_is_lent_once_the_borrowing_device_heads_where_it_sees_it(
        room: Room) -> None:  # noqa: F811
    """With lend_in_view (the edge's default) the place's keyframes the borrowing device does
    not see from where it heads are held back — here ar1's keyframes 180 and 210 and its
    keyframe 999, which has no points, seen from the room's first frame — and lent once it
    heads where they are; each counts as adopted at the slot it was first offered (a loop
    across devices closes with a device's keyframes that were there first). A lost device is
    lent everything: wherever it turns up, the edge relocalises it in its archive."""
    _, archive, _ = room
    cores = _room_and_newcomer(room)
    merging = PlaceMerging(lambda: cores, background=False)
    _walk_ar2_into_the_room(room, cores, merging)
    assert merging.joined == {"ar2": "ar1"}
    ar1 = foreign_tag(source_of("ar1"))
    _tracked_at(cores["ar2"], 4, room[0].read(4).pose)   # type: ignore[attr-defined]
    merging.before_slot_end("ar2", 4)
    held = {ar1 | k for k in (180, 210, 999)}
    assert {kf.id for kf in cores["ar2"].archive} == {ar1 | kf.id for kf in archive} - held
    _tracked_at(cores["ar2"], 7, room[0].read(184).pose)  # type: ignore[attr-defined]
    assert merging.before_slot_end("ar2", 7) == (None, 2, [])       # 180 and 210 now
    assert cores["ar2"].back_end.adopted_at[ar1 | 180] == 4
    assert cores["ar2"].back_end.adopted_at[ar1 | 0] == 4
    _tracked_at(cores["ar2"], 8, None)                   # lost: 999 too
    assert merging.before_slot_end("ar2", 8) == (None, 1, [])
    assert cores["ar2"].back_end.adopted_at[ar1 | 999] == 4
    # each copy keeps the camera that took it, ar1's: welded, adjusted and aligned with it
    copies = [kf for kf in cores["ar2"].archive if kf.id & ar1]
    assert copies and all(kf.intrinsics is not None and
                          np.array_equal(kf.intrinsics, cores["ar1"].k) for kf in copies)
    # lending everything at once (lend_in_view false) adopts the three at the first round
    eager = _room_and_newcomer(room)
    at_once = PlaceMerging(lambda: eager, background=False, lend_in_view=False)
    _walk_ar2_into_the_room(room, eager, at_once)
    _tracked_at(eager["ar2"], 4, room[0].read(4).pose)   # type: ignore[attr-defined]
    assert at_once.before_slot_end("ar2", 4) == (None, len(archive) + 1, [])


def test_a_copy_its_device_no_longer_sees_goes_back_and_is_lent_again_where_it_comes(
        room: Room) -> None:  # noqa: F811
    """With lent_unseen_slots, a copy in the borrower's archive that its device has neither
    held nor seen for that many slots leaves the borrower's map and goes back to its lender:
    ar1's keyframes 180 and 210, lent when ar2 headed where they are (slot 7), leave two slots
    after ar2 turned away (slot 9) while the copies it still sees stay. Where ar2 comes back
    they are lent again, still counted as adopted at the slot they were first offered at (a
    loop across devices closes with a device that was there first). The slots are counted
    from the last that saw or held a copy, not from the one that lent it; one held in the
    device's map stays there.
    Without it (0, the default) a copy stays."""
    for unseen_slots in (2, 0):
        cores = _room_and_newcomer(room)
        merging = PlaceMerging(lambda: cores, background=False,  # noqa: B023
                               unseen_slots=unseen_slots)
        _walk_ar2_into_the_room(room, cores, merging)
        ar1 = foreign_tag(source_of("ar1"))
        there = room[0].read(184).pose    # type: ignore[attr-defined]
        away = room[0].read(4).pose       # type: ignore[attr-defined]
        _tracked_at(cores["ar2"], 4, away)
        merging.before_slot_end("ar2", 4)
        seen_from_away = {kf.id for kf in cores["ar2"].archive}
        _tracked_at(cores["ar2"], 7, there)
        assert merging.before_slot_end("ar2", 7) == (None, 2, [])
        for slot in (8, 9):
            _tracked_at(cores["ar2"], slot, away)
            merging.before_slot_end("ar2", slot)
            copies = {kf.id for kf in cores["ar2"].archive}
            gone = {ar1 | 180, ar1 | 210} if unseen_slots and slot == 9 else set()
            assert copies == (seen_from_away | {ar1 | 180, ar1 | 210}) - gone
        if not unseen_slots:
            continue
        assert ar1 | 180 not in cores["ar2"].back_end.adopted_at
        _tracked_at(cores["ar2"], 10, there)
        assert merging.before_slot_end("ar2", 10) == (None, 2, [])     # lent again
        assert cores["ar2"].back_end.adopted_at[ar1 | 180] == 4
        assert cores["ar2"].back_end.adopted_at[ar1 | 210] == 4
        # every copy counts its unseen slots from the last slot that held or saw it (10),
        # not from the slot that lent it: turned to face away from the room, ar2 sees none
        assert {kf.id for kf in cores["ar2"].archive} == seen_from_away | {ar1 | 180, ar1 | 210}
        # ar1's keyframe 0 restored into ar2's map: held, it stays while the device holds it
        cores["ar2"].back_end.restore([ar1 | 0], [], 10)
        facing_out = there @ np.diag([-1.0, 1.0, -1.0, 1.0])
        for slot, archived in ((11, len(seen_from_away) + 1), (12, 0)):
            _tracked_at(cores["ar2"], slot, facing_out)
            merging.before_slot_end("ar2", slot)
            assert len(cores["ar2"].archive) == archived
        # evicted at slot 13, it goes back two slots after the last that held it
        cores["ar2"].back_end.evict_to_archive([ar1 | 0], 13)
        for slot, archived in ((13, {ar1 | 0}), (14, set())):
            _tracked_at(cores["ar2"], slot, facing_out)
            merging.before_slot_end("ar2", slot)
            assert {kf.id for kf in cores["ar2"].archive} == archived


def test_a_loop_across_devices_closes_only_with_copies_adopted_a_while_before(
        room: Room, tmp_path: Path) -> None:  # noqa: F811
    """A map may close a loop with the copies of its place's other devices only once it
    adopted them ACROSS_GAP_SLOTS before: where two devices walk one place at once, each
    would bend towards keyframes the other's walk moves meanwhile. The slots copies were
    adopted at survive a restart; ``loops_across_devices: false`` closes none."""
    core, copies = _borrower(room)              # the copies adopted at slot 1
    ids = frozenset(kf.id for kf in copies.values())
    poses = core.back_end.keyframe_poses()
    assert core.back_end._across(poses, 1 + ACROSS_GAP_SLOTS) == frozenset()   # no tags yet
    core.back_end.loop_across = frozenset({foreign_tag(0)})
    assert core.back_end._across(poses, ACROSS_GAP_SLOTS) == frozenset()
    assert core.back_end._across(poses, 1 + ACROSS_GAP_SLOTS) == ids
    path = tmp_path / "edge.npz"
    core.map.save(path, **core.back_end.checkpoint_arrays())
    again = MapBackEnd(core.back_end.config, room[0].intrinsics, path)  # type: ignore[attr-defined]
    assert again.adopted_at == {k: 1 for k in ids}
    off = MapBackEnd(dataclasses.replace(core.back_end.config, loops_across_devices=False))
    off.adopted_at, off.loop_across = dict(again.adopted_at), frozenset({foreign_tag(0)})
    assert off._across(poses, 100) == frozenset()


def test_an_edge_restarted_from_its_checkpoints_serves_each_device_in_the_place_it_left(
        room: Room, tmp_path: Path) -> None:  # noqa: F811
    """ar2 joined ar1's place and the two maps lent each other their keyframes; the edge
    restarts from its checkpoints and its devices come back the other way round. ar2 waits
    in a place of its own while ar1 is not served, and rejoins ar1's place when it is: no
    look, no keyframe adopted a second time though ar2 now lends first, each map in the frame
    it was in, the lenders' loops followed so far kept."""
    cores = _room_and_newcomer(room, tmp_path)
    merging = PlaceMerging(lambda: cores, background=False)
    assert [merging.serve(d) for d in cores] == ["", ""]          # fresh maps
    assert _walk_ar2_into_the_room(room, cores, merging)[3] is not None
    merging.before_slot_end("ar2", 4)
    merging.before_slot_end("ar1", 4)
    held = {d: sorted(kf.id for kf in core.archive) for d, core in cores.items()}
    frames = {d: core.frame_correction.copy() for d, core in cores.items()}
    followed = {d: merging.membership(d) for d in cores}
    for core in cores.values():
        core.save_checkpoint()
        core.close()

    restarted: dict[str, EdgeMapperCore] = {}
    filed: list[tuple[str, int]] = []

    class Filing(KeyFrameDatabase):
        def add(self, map_name: str, kf_id: int, descriptors: np.ndarray) -> None:
            filed.append((map_name, kf_id))
            super().add(map_name, kf_id, descriptors)

    again = PlaceMerging(lambda: restarted, background=False,
                         database=Filing(learn_from=2000))
    restarted["ar2"] = _core(checkpoint=tmp_path / "edge.ar2.npz")
    assert again.serve("ar2") == ("its place's root ar1 is not served: a place of its own "
                                  "until ar1 is, or a look finds the place again")
    assert again.joined == {} and again.membership("ar2").root == "ar1"
    restarted["ar1"] = _core(checkpoint=tmp_path / "edge.ar1.npz")
    store = restarted["ar1"].back_end.store
    kept = list(store.descriptors())
    # an archive holds keyframes in the order they left the slice, which a policy that
    # evicts by utility makes other than their capture order
    store.descriptors = lambda: iter(kept[::-1])                     # type: ignore[method-assign]
    assert again.serve("ar1") == "ar2 back in its place"
    assert again.joined == {"ar2": "ar1"}
    assert restarted["ar2"].archive.words.source() is restarted["ar1"].archive.words
    assert again.others("ar1") == [] and again.others("ar2") == []
    assert again.before_slot_end("ar1", 5) == (None, 0, [])       # ar2 lends first now
    assert again.before_slot_end("ar2", 5) == (None, 0, [])
    assert {d: sorted(kf.id for kf in core.archive) for d, core in restarted.items()} == held
    for d, core in restarted.items():
        np.testing.assert_allclose(core.frame_correction, frames[d])
        assert again.membership(d) == followed[d]
    # the keyframe database holds each restored map's own keyframes, not the copies it
    # adopted (those are their lender's): ar2 holds the room's keyframes as copies, and its
    # own three have no points here, so nothing of ar2's map is filed
    again.database.scores([], [])
    assert again.database.keyframes("ar1") == len(room[1])
    # in capture order, as they were uploaded, whatever order the store holds them in: a row
    # of the database sums neighbours
    mine = [kf for d, kf in filed if d == "ar1"]
    assert mine == sorted(mine) and len(mine) > len(room[1]) // 2
    assert len(restarted["ar2"].archive) > len(room[1]) and again.database.keyframes("ar2") == 0


def test_the_keyframes_held_back_keep_the_slot_they_were_first_offered_at_over_a_restart(
        room: Room, tmp_path: Path) -> None:  # noqa: F811
    """ar1's keyframes 180, 210 and 999, out of ar2's view at slot 4, are offered then and
    held back; the edge restarts from its checkpoints, and when ar2 heads where 180 and 210
    are (slot 9) they are lent as adopted at slot 4, as they would have been without the
    restart — not at the restart's first offer: a loop across devices with them may close
    as soon as it could have."""
    cores = _room_and_newcomer(room, tmp_path)
    merging = PlaceMerging(lambda: cores, background=False)
    for device in cores:
        merging.serve(device)
    _walk_ar2_into_the_room(room, cores, merging)
    _tracked_at(cores["ar2"], 4, room[0].read(4).pose)   # type: ignore[attr-defined]
    merging.before_slot_end("ar2", 4)
    assert merging.membership("ar2").offered == {"ar1": {180: 4, 210: 4, 999: 4}}
    for core in cores.values():
        core.save_checkpoint()
        core.close()
    restarted: dict[str, EdgeMapperCore] = {}
    again = PlaceMerging(lambda: restarted, background=False)
    for device in ("ar1", "ar2"):
        restarted[device] = _core(checkpoint=tmp_path / f"edge.{device}.npz")
        again.serve(device)
    assert again.joined == {"ar2": "ar1"}
    assert again.membership("ar2").offered == {"ar1": {180: 4, 210: 4, 999: 4}}
    _tracked_at(restarted["ar2"], 9, room[0].read(184).pose)  # type: ignore[attr-defined]
    assert again.before_slot_end("ar2", 9)[1] == 2
    ar1 = foreign_tag(source_of("ar1"))
    assert restarted["ar2"].back_end.adopted_at[ar1 | 180] == 4
    assert restarted["ar2"].back_end.adopted_at[ar1 | 210] == 4


def test_a_device_whose_copies_would_share_another_devices_tag_lends_nothing(
        room: Room) -> None:  # noqa: F811
    """Two device names whose tags collide (1 in ~3 000 edges of fifty devices): a map could
    not tell their keyframes and points apart, so neither lends to a map while the other is
    served, and the edge says so once; with the other one gone, the lending goes ahead."""
    seen: dict[int, str] = {}
    names = (f"ar{i}" for i in range(100_000))
    first, second = next((seen[source_of(n)], n) for n in names
                         if seen.setdefault(source_of(n), n) != n)
    cores = _room_and_newcomer(room)
    cores = {first: cores["ar1"], "borrower": cores["ar2"], second: _core()}
    merging = PlaceMerging(lambda: cores, background=False)
    merging.joined["borrower"] = first                  # as a merge left it
    assert merging.lend_all("borrower", [first], 1)[0].adopted == 0
    assert merging.tag_clashes() == [f"{first}'s keyframes are not lent to this map: their "
                                     f"tag is {second}'s too (rename one of the devices)"]
    assert merging.lend_all("borrower", [first], 2)[0].adopted == 0
    assert merging.tag_clashes() == []                  # said once
    del cores[second]
    merging.forget(second)
    assert merging.lend_all("borrower", [first], 3)[0].adopted == len(room[1]) + 1


def test_a_device_served_with_a_new_map_lends_its_new_keyframes_under_a_new_tag(
        room: Room, tmp_path: Path) -> None:  # noqa: F811
    """ar1 lent its map of the room to ar2; then ar1 started again (or was reclaimed) and the
    edge serves it with a new map, whose keyframe and point ids are the old map's ids again.
    Once the new map is in the place, ar2 adopts its keyframes as copies of their own — not
    taken for the old copies it holds under the same ids — and a restarted edge, or one
    that starts the device's next map before its first checkpoint, keeps counting the
    device's maps."""
    cores = _room_and_newcomer(room, tmp_path)
    merging = PlaceMerging(lambda: cores, background=False)
    for d in cores:
        merging.serve(d)
    merging.joined["ar2"] = "ar1"                      # as a merge left it
    lent = len(room[1]) + 1
    assert merging.lend_all("ar2", ["ar1"], 1)[0].adopted == lent
    first = foreign_tag(source_of("ar1"))
    cores["ar1"].save_checkpoint()

    # ar1 starts again: its map set aside (as its link does), a new one holding the same
    # keyframe ids; once merged into ar2's place it lends again
    cores["ar1"].close()
    checkpoint = tmp_path / "edge.ar1.npz"
    checkpoint.replace(set_aside(checkpoint))
    merging.forget("ar1")
    cores["ar1"] = _room_and_newcomer(room)["ar1"]
    cores["ar1"].checkpoint = checkpoint
    merging.serve("ar1")
    assert merging.membership("ar1").run == 1 and merging.joined == {}
    merging.joined["ar1"] = "ar2"                      # ar2 is its place's root now
    second = foreign_tag(source_of("ar1", 1))
    assert second != first
    assert merging.lend_all("ar2", ["ar1"], 2)[0].adopted == lent
    tags = [kf.id & ~((1 << 40) - 1) for kf in cores["ar2"].archive]
    assert tags.count(first) == lent and tags.count(second) == lent
    # a new copy's points are its own, not the old copies' of the same ids
    copy = cores["ar2"].archive.get(second | 270)
    assert all(p & ~((1 << 40) - 1) in (second, 0) for p in copy.point_ids.tolist())

    # the run is in the new map's checkpoint; an edge that starts yet another map before
    # that map's first checkpoint learns it from the map set aside
    cores["ar1"].save_checkpoint()
    assert PlaceMembership.read(np.load(checkpoint)).run == 1
    checkpoint.replace(set_aside(checkpoint))
    fresh = PlaceMerging(lambda: {"ar1": _core(checkpoint=checkpoint)}, background=False)
    fresh.serve("ar1")
    assert fresh.membership("ar1").run == 2 and fresh.source("ar1") == source_of("ar1", 2)


def test_a_later_device_that_the_earlier_one_finds_in_its_map_joins_the_earlier_ones_frame(
        room: Room) -> None:  # noqa: F811
    """A device walking ahead of an earlier one: the later device holds the room, the earlier
    device's keyframes come to it. The earlier device's looks find them in the later
    device's map; the later map then joins the earlier one's frame by the inverse motion —
    at the later device's slot end, where its map update carries it — and the earlier map
    stays where it is."""
    _, archive, _ = room
    cores = {"ar1": _core(), "ar2": _core()}
    for kf in archive:                                 # the later device's map of the room
        cores["ar2"].archive.add(kf)
    cores["ar2"].map.add_keyframe(999, archive.get(270).pose)
    for core in cores.values():
        core.back_end.device.k = room[0].intrinsics                    # type: ignore[attr-defined]
    merging = PlaceMerging(lambda: cores, background=False)
    assert merging.others("ar1") == ["ar2"]
    for slot, (key, frame) in enumerate(((10, 4), (11, 64), (12, 124))):
        cores["ar1"].map.add_keyframe(key, _second_pose(room, frame))
        merging.keyframe("ar1", _payload(room, frame, key))
        assert merging.take("ar1") is None             # the earlier map never moves
        merging.look("ar1", slot)
    assert merging.take("ar1") is None                 # the earlier map never moves
    assert merging.joined == {"ar2": "ar1"}            # the later map moved at once
    # the earlier device's slot end tells it too: a moved device whose walk has ended has
    # no slot end of its own
    told = merging.brought("ar1")
    assert [(e.device, e.place) for e in told] == [("ar2", "ar1")] and not merging.brought("ar1")
    event = merging.take("ar2")                        # and its slot end tells it
    assert event is not None and event.device == "ar2" and event.place == "ar1"
    assert merging.joined == {"ar2": "ar1"}
    np.testing.assert_allclose(cores["ar1"].frame_correction, np.eye(4))
    # the room (ar2's frame is the room's) now lies where ar1's frame has it
    off = SECOND_IN_FIRST @ cores["ar2"].frame_correction
    assert np.linalg.norm(off[:3, 3]) < 0.03 and rotation_angle_deg(off[:3, :3]) < 0.5
    np.testing.assert_allclose(cores["ar2"].archive.get(270).pose,
                               event.merge.alignment @ archive.get(270).pose)
    assert event.merge.place in (10, 11, 12) and event.merge.joining in archive
    assert merging.others("ar1") == [] and merging.others("ar2") == []
    assert merging.take("ar2") is None                 # told once


def test_two_places_each_joined_by_another_device_become_one_in_the_earlier_frame(
        room: Room) -> None:  # noqa: F811
    """ar3 joined ar2's place; ar1, on its own, finds itself in ar2's map: the later place —
    ar2 and ar3 together — moves into ar1's frame at once by the inverse motion, each of its
    devices told at its own next slot end, and from then on every device of the place lends
    to every other."""
    _, archive, _ = room
    cores = {"ar1": _core(), "ar2": _core(), "ar3": _core()}
    for kf in archive:
        cores["ar2"].archive.add(kf)
    cores["ar2"].map.add_keyframe(999, archive.get(270).pose)
    cores["ar3"].map.add_keyframe(5, archive.get(270).pose)   # ar3's map, in ar2's frame
    for core in cores.values():
        core.back_end.device.k = room[0].intrinsics                    # type: ignore[attr-defined]
    merging = PlaceMerging(lambda: cores, background=False)
    merging.joined["ar3"] = "ar2"                      # as a merge before left it
    assert merging.place_of("ar3") == ["ar2", "ar3"] and merging.others("ar3") == []
    assert merging.others("ar1") == ["ar2", "ar3"] and merging.others("ar2") == ["ar1"]
    # its looks go to ar2's map and ar3's in turn: those in ar2's (slots 0, 2, 4) find it
    for slot, (key, frame) in enumerate(((10, 4), (11, 34), (12, 64), (13, 94), (14, 124))):
        cores["ar1"].map.add_keyframe(key, _second_pose(room, frame))
        merging.keyframe("ar1", _payload(room, frame, key))
        assert merging.take("ar1") is None
        merging.look("ar1", slot)
    assert merging.take("ar1") is None
    assert merging.joined == {"ar2": "ar1", "ar3": "ar1"}
    assert merging.place_of("ar2") == ["ar1", "ar2", "ar3"]
    for device in ("ar2", "ar3"):
        off = SECOND_IN_FIRST @ cores[device].frame_correction
        assert np.linalg.norm(off[:3, 3]) < 0.03 and rotation_angle_deg(off[:3, :3]) < 0.5
    event = merging.take("ar3")
    assert event is not None and (event.device, event.place, event.via) == ("ar3", "ar1", "ar2")
    moved = merging.take("ar2")                        # the map that met ar1's place
    assert moved is not None and (moved.place, moved.via) == ("ar1", "")
    np.testing.assert_allclose(cores["ar3"].map.keyframes[5].pose,
                               event.merge.alignment @ archive.get(270).pose)
    # ar3 now borrows from ar1 as well as from ar2
    _, adopted, _ = merging.before_slot_end("ar3", 4)
    assert {kf.id & ~0xFFFF_FFFF for kf in cores["ar3"].archive} >= {
        foreign_tag(source_of("ar1")), foreign_tag(source_of("ar2"))}
    assert adopted == len(cores["ar3"].archive)


def test_a_look_made_before_the_map_moved_is_dropped(room: Room) -> None:  # noqa: F811
    """A merge confirmed against the joining map's poses before a loop moved that map would
    put it off by the loop's correction: it is not applied (the device goes on looking)."""
    _, archive, _ = room
    cores = {"ar1": _core(), "ar2": _core()}
    for kf in archive:
        cores["ar1"].archive.add(kf)
    cores["ar1"].map.add_keyframe(999, archive.get(270).pose)
    for core in cores.values():
        core.back_end.device.k = room[0].intrinsics                    # type: ignore[attr-defined]
    merging = PlaceMerging(lambda: cores, background=False)
    for slot, (key, frame) in enumerate(((10, 4), (11, 64), (12, 124))):
        cores["ar2"].map.add_keyframe(key, _second_pose(room, frame))
        merging.keyframe("ar2", _payload(room, frame, key))
        merging.take("ar2")
        merging.look("ar2", slot)
    loop = np.eye(4)
    loop[0, 3] = 0.05                                  # a loop corrected the map meanwhile
    cores["ar2"].back_end.align(loop)
    assert merging.take("ar2") is None and merging.joined == {}
    np.testing.assert_allclose(cores["ar2"].frame_correction, loop)


def _map_of(archived: ArchivedKeyFrame) -> KeyFrameMap:
    """A map holding one keyframe of the room, its points under their own ids."""
    m = KeyFrameMap()
    m.next_point_id = int(archived.point_ids.max()) + 1
    restore_into(m, archived)
    return m


def _renumbered(archived: ArchivedKeyFrame, offset: int) -> ArchivedKeyFrame:
    """The keyframe as another device's map numbers it (its points' ids moved by
    ``offset``): nothing but the geometry and the descriptors tells its points are the
    same corners."""
    return dataclasses.replace(archived, point_ids=archived.point_ids + offset)


def test_an_adopted_keyframe_takes_the_ids_of_the_points_the_map_has_already(
        room: Room) -> None:  # noqa: F811
    """The first device's keyframe of the room (frame 60), adopted by a map that holds the
    keyframe of frame 30: the corners both see keep the adopting map's ids (each within 10 cm
    of the adopting map's point), the rest and the keyframe itself carry the source's tag."""
    seq, archive, _ = room
    mine = _map_of(archive.get(30))
    theirs = _renumbered(archive.get(60), 100_000)
    camera = Camera(seq.intrinsics)                              # type: ignore[attr-defined]
    adopted = welded(theirs, 0, mine, camera, slot=3)
    assert adopted.id == foreign_tag(0) | 60 and is_foreign(adopted.id)
    assert adopted.archived_slot == 3
    own = [(row, int(p)) for row, p in enumerate(adopted.point_ids) if not is_foreign(int(p))]
    assert len(own) >= 30, len(own)
    assert len({p for _, p in own}) == len(own)                # one corner, one point
    for row, p in own:
        assert np.linalg.norm(theirs.positions[row] - mine.points[p].position) <= 0.10
    tagged = [int(p) for p in adopted.point_ids if is_foreign(int(p))]
    assert tagged and all(p & ~foreign_tag(0) >= 100_000 for p in tagged)


def test_a_point_the_lender_had_adopted_keeps_its_devices_tag_when_lent_on() -> None:
    """A lender's own keyframe observes points of a third device's copies it matched (tagged
    with that device's tag): lent on, they keep that id, and only the lender's own points
    take the lender's tag — tagged twice, source 1's point 5 lent by source 0 read as source
    2's point 5, another device's corner."""
    none = np.zeros((2, 3))
    third = foreign_tag(1) | 5
    kf = ArchivedKeyFrame(9, np.eye(4), np.array([third, 6], dtype=np.int64), none,
                          np.zeros((2, 32), dtype=np.uint8), none, 0)
    adopted = welded(kf, 0, KeyFrameMap(), Camera(), slot=1)
    assert adopted.point_ids.tolist() == [third, foreign_tag(0) | 6]
    assert foreign_tag(2) | 5 not in adopted.point_ids.tolist()


def test_a_welded_keyframe_names_each_point_once() -> None:
    """The lender's keyframe holds a third device's point (adopted by both maps, tagged in
    both) and sees, elsewhere in its image, a corner of its own that looks like it and lies
    where it does in the borrower's map: welded, that corner keeps its own tagged id — given
    the third device's, the keyframe would name one point twice, and restoring it failed."""
    camera = Camera(np.array([[500.0, 0.0, 320.0], [0.0, 500.0, 240.0], [0.0, 0.0, 1.0]]))
    third = foreign_tag(1) | 5
    corner = np.random.default_rng(2).integers(0, 256, 32, dtype=np.uint8)
    borrower = KeyFrameMap()
    borrower.readd_point(third, np.array([0.0, 0.0, 2.0]), corner)
    kf = ArchivedKeyFrame(9, np.eye(4), np.array([third, 6], dtype=np.int64),
                          np.array([[1.0, 1.0, 2.0], [0.0, 0.0, 2.0]]),
                          np.stack([255 - corner, corner]),
                          np.array([[50.0, 50.0, 2.0], [320.0, 240.0, 2.0]]), 0)
    adopted = welded(kf, 0, borrower, camera, slot=1)
    assert adopted.point_ids.tolist() == [third, foreign_tag(0) | 6]
    restore_into(borrower, adopted)
    assert borrower.keyframes[adopted.id].points == {third, foreign_tag(0) | 6}


def test_a_keyframe_that_names_a_point_twice_is_restored_with_it_once() -> None:
    """An archived keyframe written before welding kept its ids apart may name one point
    twice: restored, the point comes back once and the keyframe observes it."""
    none = np.zeros((2, 3))
    kf = ArchivedKeyFrame(3, np.eye(4), np.array([7, 7], dtype=np.int64), none,
                          np.zeros((2, 32), dtype=np.uint8),
                          np.array([[10.0, 10.0, 1.0], [12.0, 10.0, 1.0]]), 0)
    m = KeyFrameMap()
    m.next_point_id = 8
    assert restore_into(m, kf) == [7]
    assert set(m.points) == {7} and m.keyframes[3].points == {7}


def test_a_restored_adopted_keyframe_joins_the_map_through_its_welded_points(
        room: Room) -> None:  # noqa: F811
    """Adopted into the archive and restored, the other device's keyframe shares the welded
    corners with the map's own keyframe (the map stays one connected graph), and a loop the
    map closes later moves its own keyframes and never the adopted one."""
    seq, archive, _ = room
    core = _core(vmax=4)
    core.back_end.device.k = seq.intrinsics                             # type: ignore[attr-defined]
    core.map.next_point_id = int(archive.get(30).point_ids.max()) + 1
    restore_into(core.map, archive.get(30))
    adopted = welded(_renumbered(archive.get(60), 100_000), 0, core.map, core.camera, slot=1)
    core.back_end.adopt([adopted, adopted])                      # twice: kept once
    assert adopted.id in core.archive and len(core.archive) == 1
    core.back_end.restore([adopted.id], [], slot=2)
    shared = core.map.keyframes[30].points & core.map.keyframes[adopted.id].points
    assert len(shared) >= 30
    moved = np.eye(4)
    moved[0, 3] = 0.1
    before = core.map.keyframes[adopted.id].pose.copy()
    correct_map(core.map, {30: moved})
    np.testing.assert_allclose(core.map.keyframes[adopted.id].pose, before)
    np.testing.assert_allclose(core.map.keyframes[30].pose[0, 3],
                               archive.get(30).pose[0, 3] + 0.1)
    assert correction_for({30: moved}, adopted.id) is None


def test_a_borrowers_bundle_adjustment_moves_the_newest_copies_and_holds_its_own(
        room: Room) -> None:  # noqa: F811
    """Local bundle adjustment in a map that adopted another device's keyframe: the window is
    the newest ids, the copy's tagged id sorts after every own one, so the copy moves to fit
    the map's own keyframes and they hold still — the behaviour measured better than moving
    the map's own newest keyframe against the copy held still (docs/results/shared-map.md,
    "Which keyframes a merged map adjusts"). A change of it must be measured again."""
    seq, archive, _ = room
    core = _core(vmax=6)
    core.back_end.device.k = seq.intrinsics                             # type: ignore[attr-defined]
    core.map.next_point_id = int(max(archive.get(k).point_ids.max() for k in (30, 60))) + 1
    restore_into(core.map, archive.get(30))
    restore_into(core.map, archive.get(60))
    copy = welded(_renumbered(archive.get(90), 100_000), 0, core.map, core.camera, slot=1)
    core.back_end.adopt([copy])
    core.back_end.restore([copy.id], [], slot=2)
    off = np.eye(4)
    off[0, 3] = 0.02
    core.map.keyframes[60].pose = core.map.keyframes[60].pose @ off
    own_pose = core.map.keyframes[60].pose.copy()
    copy_pose = core.map.keyframes[copy.id].pose.copy()
    core.back_end.config = dataclasses.replace(core.back_end.config, ba_window=1)
    result = core.back_end.optimise()
    assert result is not None and not result.refused
    assert set(result.poses) >= {60, copy.id}         # 60 sees the window's points
    np.testing.assert_array_equal(core.map.keyframes[60].pose, own_pose)
    moved = np.linalg.norm(core.map.keyframes[copy.id].pose[:3, 3] - copy_pose[:3, 3])
    assert moved > 0.005, moved


def test_a_merged_map_takes_its_devices_first_keyframes_where_the_merge_put_them() -> None:
    """The keyframe gate measures a new keyframe's reach from the device's first camera when
    no keyframe is nearer in time: after a merge that camera is where the alignment put it,
    2 m from the place's origin — a keyframe of the device's first second posed there is
    plausible, the same pose in a map that never merged is not."""
    posed = SECOND_IN_FIRST.copy()
    posed[0, 3] += 0.02
    upload = KeyFramePayload(frame_id=5, slot=0, pose=posed, intrinsics=np.diag([500.0, 500, 1]),
                             keypoints=np.zeros((0, 2)), descriptors=np.zeros((0, 32), np.uint8),
                             depths=np.zeros(0), point_ids=np.zeros(0, np.uint64), stamp=0.2)
    merged, alone = _core(), _core()
    merged.align(SECOND_IN_FIRST)
    assert merged.back_end.integrate(upload, -1).refused == ""
    assert "out of reach" in alone.back_end.integrate(upload, -1).refused
    np.testing.assert_allclose(merged.back_end.checkpoint_arrays()["origin"], SECOND_IN_FIRST)


def test_adopted_keyframes_are_written_beside_the_slots_for_a_restart(
        room: Room, tmp_path: Path) -> None:  # noqa: F811
    """A merge adopts the other map's keyframes by the hundred: their archive files are
    written on the loop closer's worker, not in the slot — and are there once it is done."""
    _, archive, _ = room
    k = np.array([[500.0, 0.0, 320.0], [0.0, 500.0, 240.0], [0.0, 0.0, 1.0]])
    core = EdgeMapperCore(make_policy("lff"), k, EdgeConfig(slot=SlotConfig(vmax=4)),
                          tmp_path / "edge.npz")
    core.back_end.device.k = room[0].intrinsics                        # type: ignore[attr-defined]
    lent = [welded(kf, 0, core.map, core.camera, slot=1) for kf in archive]
    assert core.back_end.adopt(lent) == []
    core.close()                                               # the worker's queue done
    written = sorted(int(f.stem.split("-")[1]) for f in
                     archive_folder(tmp_path / "edge.npz").glob("keyframe-*.npz"))
    assert written == sorted(kf.id for kf in lent)


def test_a_lenders_loop_moves_the_copies_lent_before_it_never_a_keyframe_made_before_them(
        room: Room) -> None:  # noqa: F811
    """The lender closes a loop after lending keyframes 60, 90 and 120 (120 newer than its
    loop's graph: it moves as the lender's head did). The borrower's copies follow: the one
    restored into its map with the points only copies observe, the archived ones with their
    points. The borrower's own keyframe 30 and the corners the copies were welded to stay:
    the borrower made them before the copies came, and did not inherit the lender's drift.
    Followed once, a loop is not applied again."""
    core, copies = _borrower(room)
    own_before = core.map.keyframes[30].pose.copy()
    in_map = core.map.keyframes[copies[60].id]
    welded_points = in_map.points & core.map.keyframes[30].points
    only_copy = [p for p in in_map.points if core.map.points[p].observers == {copies[60].id}]
    assert len(welded_points) >= 30 and only_copy
    before = {p: core.map.points[p].position.copy() for p in [*welded_points, *only_copy]}
    pose_60 = in_map.pose.copy()
    archived_before = {k: core.archive.get(copies[k].id).pose.copy() for k in (90, 120)}

    lender = _lender_loop()
    followed, moves = follow_lender_loops(core.back_end, lender.back_end, 0, 0)
    assert followed == 1 and [(m.copies, m.own) for m in moves] == [(3, 0)]

    np.testing.assert_allclose(in_map.pose, C60 @ pose_60)
    for p in only_copy:
        np.testing.assert_allclose(core.map.points[p].position, before[p] + [0.02, 0, 0])
    for k in (90, 120):                              # 120 is newer than the graph: as 90
        np.testing.assert_allclose(core.archive.get(copies[k].id).pose,
                                   C90 @ archived_before[k])
    np.testing.assert_allclose(core.map.keyframes[30].pose, own_before)
    for p in welded_points:
        np.testing.assert_allclose(core.map.points[p].position, before[p])
    np.testing.assert_allclose(core.back_end.device.frame_correction, np.eye(4))
    assert follow_lender_loops(core.back_end, lender.back_end, 0, 1) == (1, ())
    np.testing.assert_allclose(in_map.pose, C60 @ pose_60)


def test_a_borrowers_keyframe_posed_on_a_copy_moves_with_it_and_so_does_its_devices_frame(
        room: Room) -> None:  # noqa: F811
    """The borrower's device tracked on the restored copy of the lender's keyframe 60: its
    keyframe 150 observes forty of the points the copy brought. The lender's loop moves the
    copy 2 cm; keyframe 150 inherited the copy's error and moves the 2 cm with it, its own
    points with it, while keyframe 30, the map's oldest, stays (the map's frame; their step
    shares no point, and bends); the frame the device is told moves by the head's correction
    from the next map version on, and the move is kept for the borrower's own borrowers
    (carried: they move their copies by it, never their own keyframes)."""
    core, copies = _borrower(room)
    copy = core.map.keyframes[copies[60].id]
    brought = sorted(p for p in copy.points if is_foreign(p))[:40]
    core.map.add_keyframe(150, copy.pose.copy())
    core.map.observe_many(150, brought, [[320.0, 240.0]] * len(brought), [1.0] * len(brought))
    made = core.map.add_point(copy.pose[:3, 3] + [0.0, 0.0, 1.0], np.zeros(32, np.uint8))
    core.map.observe(150, made, (320.0, 240.0), 1.0)
    own_before = {k: core.map.keyframes[k].pose.copy() for k in (30, 150)}
    made_before = core.map.points[made].position.copy()

    core.version = 2                                   # the device holds map version 2
    moved = core.back_end.follow(_lender_loop().back_end.applied_loops[0], foreign_tag(0))
    assert (moved.copies, moved.own, moved.refused) == (3, 2, "")
    assert 0.018 < moved.own_moved_m <= 0.02
    np.testing.assert_allclose(core.map.keyframes[30].pose, own_before[30], atol=1e-9)
    head = core.map.keyframes[150].pose @ np.linalg.inv(own_before[150])
    np.testing.assert_allclose(head, C60, atol=2e-3)
    np.testing.assert_allclose(core.map.points[made].position,
                               head[:3, :3] @ made_before + head[:3, 3], atol=1e-9)
    np.testing.assert_allclose(core.back_end.device.frame_correction, head, atol=1e-9)
    np.testing.assert_allclose(core.back_end.device.frame_correction_at(2), np.eye(4))
    np.testing.assert_allclose(core.back_end.device.frame_correction_at(3), head, atol=1e-9)
    assert [loop.carried for loop in core.back_end.applied_loops] == [True]


#: the lender's loop: its keyframe 60 moved 2 cm along x, 90 (the graph's newest) 4 cm
C60, C90 = np.eye(4), np.eye(4)
C60[0, 3], C90[0, 3] = 0.02, 0.04


def _lender_loop() -> EdgeMapperCore:
    """A lender whose map applied one loop (:data:`C60`, :data:`C90`)."""
    lender = _core()
    lender.back_end.applied_loops.append(AppliedLoop({60: C60, 90: C90}))
    return lender


def test_a_move_another_map_carried_moves_the_copies_never_the_maps_own_again(
        room: Room) -> None:  # noqa: F811
    """The lender's keyframes moved because it followed a loop of this very map: the copies
    follow, the map's own keyframes stay — carried back, the move would echo between the
    two maps slot after slot."""
    core, copies = _borrower(room)
    own_before = core.map.keyframes[30].pose.copy()
    pose_60 = core.map.keyframes[copies[60].id].pose.copy()
    moved = core.back_end.follow(AppliedLoop({60: C60}, carried=True), foreign_tag(0))
    assert (moved.copies, moved.own) == (3, 0)         # 90 and 120 as the head, 60
    np.testing.assert_allclose(core.map.keyframes[copies[60].id].pose, C60 @ pose_60)
    np.testing.assert_allclose(core.map.keyframes[30].pose, own_before)
    np.testing.assert_allclose(core.back_end.device.frame_correction, np.eye(4))
    assert core.back_end.applied_loops == []


def _borrower(room: Room) -> tuple[EdgeMapperCore, dict[int, ArchivedKeyFrame]]:  # noqa: F811
    """A map holding the room's keyframe 30 as its own and copies of another device's 60,
    90 and 120 (60 restored into the map, welded to 30's corners): (its core, the copies by
    the lender's ids)."""
    seq, archive, _ = room
    core = _core(vmax=4)
    core.back_end.device.k = seq.intrinsics                             # type: ignore[attr-defined]
    core.map.next_point_id = int(archive.get(30).point_ids.max()) + 1
    restore_into(core.map, archive.get(30))
    copies = {k: welded(_renumbered(archive.get(k), 100_000 * (i + 1)), 0, core.map,
                        core.camera, slot=1) for i, k in enumerate((60, 90, 120))}
    core.back_end.adopt(copies.values())
    core.back_end.restore([copies[60].id], [], slot=2)
    return core, copies


def test_a_map_moved_into_another_place_takes_the_copies_it_adopted_along(
        room: Room) -> None:  # noqa: F811
    """A map that adopted another device's keyframes (60 restored, 90 and 120 archived) and
    then moves — its place merged into an earlier one — moves them with its own: lent in the
    frame it had, they would stay there, a merge's motion off (36° and 1.5 m live), and a
    third device finding one of them would join the place that far from where it is."""
    core, copies = _borrower(room)
    in_map = core.map.keyframes[copies[60].id]
    only_copy = [p for p in in_map.points if core.map.points[p].observers == {copies[60].id}]
    assert only_copy
    before = {p: core.map.points[p].position.copy() for p in only_copy}
    pose_60 = in_map.pose.copy()
    archived = {k: core.archive.get(copies[k].id) for k in (90, 120)}
    core.align(SECOND_IN_FIRST)
    np.testing.assert_allclose(core.map.keyframes[copies[60].id].pose, SECOND_IN_FIRST @ pose_60)
    for p, xyz in before.items():
        np.testing.assert_allclose(core.map.points[p].position,
                                   SECOND_IN_FIRST[:3, :3] @ xyz + SECOND_IN_FIRST[:3, 3])
    for k, kf in archived.items():
        moved = core.archive.get(copies[k].id)
        np.testing.assert_allclose(moved.pose, SECOND_IN_FIRST @ kf.pose)
        np.testing.assert_allclose(moved.positions, kf.positions @ SECOND_IN_FIRST[:3, :3].T
                                   + SECOND_IN_FIRST[:3, 3])


def test_a_loop_is_found_among_the_walks_own_keyframes_though_copies_show_the_place_too(
        room: Room) -> None:  # noqa: F811
    """A merged map's archive holds another device's copies of the place its own walk mapped
    (here: the same views, the same descriptors). A loop closes with the walk's own keyframes
    only, and place recognition ranks those alone: the copies' points, each as near to a
    descriptor as the walk's own, must not make every vote ambiguous and hide the loop."""
    seq, archive, _ = room
    merged = KeyFrameArchive(2 * len(archive))
    for kf in archive:
        merged.add(kf, write=False)
        merged.add(dataclasses.replace(kf, id=foreign_tag(0) | kf.id,
                                       point_ids=kf.point_ids | foreign_tag(0)), write=False)
    query = dataclasses.replace(_query(room, 64, 0), keyframe=1000)
    result = run_job(LoopJob((query,), merged, {}, seq.intrinsics, {}))  # type: ignore[attr-defined]
    assert result.candidate.found, result.candidate.reason
    assert result.candidate.old in (30, 60, 90) and result.candidate.inliers >= 50


def _across_job(room: Room, drift_m: float, across: bool = True,  # noqa: F811
                 start: np.ndarray | None = None) -> LoopJob:
    """A merged map whose archive holds another device's copies (ar1's tag) of the room's
    keyframes, where that device's map has them; its own walk began at ``start`` (default:
    1 m before frame 64's camera) and its keyframe 1000 sees the room's frame 64 from where
    the walk has it: the truth ``drift_m`` further along x (the two walks drifted apart since
    their maps merged). ``across``: a loop may close with every copy; else with none."""
    seq, archive, _ = room
    copies = KeyFrameArchive(len(archive))
    tag = foreign_tag(source_of("ar1"))
    for kf in archive:
        copies.add(dataclasses.replace(kf, id=tag | kf.id, point_ids=kf.point_ids | tag),
                   write=False)
    truth = seq.read(64).pose                                   # type: ignore[attr-defined]
    walked = truth.copy()
    walked[0, 3] += drift_m
    first = truth.copy() if start is None else start
    if start is None:
        first[2, 3] -= 1.0
    query = dataclasses.replace(_query(room, 64, 0), keyframe=1000)
    return LoopJob((query,), copies, {0: first, 1000: walked}, seq.intrinsics,  # type: ignore[attr-defined]
                   {0: frozenset(), 1000: frozenset()}, (),
                   {kf.id: kf.pose for kf in copies}, {},
                   frozenset(kf.id for kf in copies) if across else frozenset())


def test_a_walk_that_drifted_from_another_devices_keyframes_closes_a_loop_with_them(
        room: Room) -> None:  # noqa: F811
    """A merged map's walk comes to a place the device before it mapped, 6 cm from where
    that device's keyframes have it: the loop across devices finds one of those keyframes,
    and its graph puts the walk's keyframe back within 2 cm of the place, the walk's first
    keyframe (the map's frame) and the other device's keyframes where they were. Without the
    other device's tag among the map's ``across``, no loop: the walk's own keyframes show
    no place seen before."""
    job = _across_job(room, 0.06)
    result = run_job(job)
    assert result.candidate.found, result.candidate.reason
    assert is_foreign(result.candidate.old) and result.candidate.inliers >= 50
    assert result.closure is not None
    truth = room[0].read(64).pose                                # type: ignore[attr-defined]
    assert np.linalg.norm(result.closure.poses[1000][:3, 3] - truth[:3, 3]) < 0.02
    np.testing.assert_allclose(result.closure.poses[0], job.poses[0], atol=1e-5)
    assert set(result.closure.corrections) == {0, 1000}     # the copies hold: no correction
    alone = run_job(_across_job(room, 0.06, across=False))
    assert not alone.candidate.found and alone.closure is None


def test_a_walk_that_agrees_with_another_devices_keyframes_or_is_far_from_them_closes_none(
        room: Room) -> None:  # noqa: F811
    """The loop across devices closes only where the walk drifted from the other device's
    keyframes (ACROSS_MIN_M) and only with keyframes near the walk's camera: a walk already
    where they have the place closes none, nor does one whose map puts its camera metres
    from every copy (a look-alike place elsewhere would be searched otherwise); and one
    whose keyframe the copies would move farther than the walk can have drifted since its
    start is refused as a look-alike."""
    agrees = run_job(_across_job(room, 0.0))
    assert not agrees.candidate.found and "agrees" in agrees.candidate.reason
    far = run_job(_across_job(room, 20 * ACROSS_NEAR_M))     # out of the room
    assert not far.candidate.found and "nearby" in far.candidate.reason
    # 0.3 m off after a walk of 1 m: more than 0.10 m + 5 % of it
    drifted = run_job(_across_job(room, 0.3))
    assert not drifted.candidate.found and "drifted" in drifted.candidate.reason


def test_a_map_keeps_its_newest_applied_loops_for_its_borrowers() -> None:
    """An edge that runs for days closes loops for days: a map keeps the newest
    APPLIED_LOOPS_KEPT for the maps it lends to, counts the rest, and a borrower that
    followed some gets those after them that are still kept."""
    core = _core()
    for i in range(APPLIED_LOOPS_KEPT + 6):
        core.back_end._keep_applied(AppliedLoop({i: np.eye(4)}))
    assert len(core.back_end.applied_loops) == APPLIED_LOOPS_KEPT
    assert core.back_end.loops_applied == APPLIED_LOOPS_KEPT + 6
    assert [next(iter(loop.corrections))
            for loop in core.back_end.loops_since(APPLIED_LOOPS_KEPT + 4)] == \
        [APPLIED_LOOPS_KEPT + 4, APPLIED_LOOPS_KEPT + 5]
    assert next(iter(core.back_end.loops_since(0)[0].corrections)) == 6     # the oldest kept
    assert core.back_end.loops_since(APPLIED_LOOPS_KEPT + 6) == []


def test_a_keyframe_is_tied_to_the_copy_that_brought_the_points_it_observes() -> None:
    """Copies 10 and 20 of one lender both observe its points 2 and 3 (tagged); 10, the
    older, brought them. The map's keyframe 5 observes 1, 2, 3 (tagged) and a corner the
    copies were welded to (its own id): three ties to copy 10, none to 20. Keyframe 7
    observes 4, which only 20 brought, and an own point: one tie to 20."""
    tag = foreign_tag(0)
    points = {tag | 10: np.array([tag | 1, tag | 2, tag | 3, 50], dtype=np.int64),
              tag | 20: np.array([tag | 2, tag | 3, tag | 4, 50], dtype=np.int64),
              5: np.array([tag | 1, tag | 2, tag | 3, 50], dtype=np.int64),
              7: np.array([tag | 4, 60], dtype=np.int64)}
    assert ties_to_copies(points) == {(5, tag | 10): 3, (7, tag | 20): 1}
    assert ties_to_copies({5: np.array([50], dtype=np.int64)}) == {}


def test_a_view_two_devices_uploaded_is_lent_once_and_again_when_its_copy_leaves(
        room: Room) -> None:  # noqa: F811
    """With ``views`` (the edge's lent_view_m and lent_view_deg), a keyframe whose view a copy
    the borrower holds covers already is declined, not adopted: two devices that mapped the
    same room (the same poses, each under its own keyframe and point ids) lend the borrower
    one copy a view,
    the first lender's. A declined keyframe is offered again once the copy that covered it
    has left the borrower; without ``views`` every keyframe of both is adopted."""
    _, archive, _ = room
    offset = 1000

    def lenders() -> tuple[EdgeMapperCore, list[Lender]]:
        first, second, borrower = _core(), _core(), _core()
        for kf in archive:
            first.archive.add(kf)
            second.archive.add(dataclasses.replace(_renumbered(kf, 1 << 20), id=kf.id + offset))
        for core in (first, second, borrower):
            core.back_end.device.k = room[0].intrinsics             # type: ignore[attr-defined]
        return borrower, [Lender(first.back_end, 1, set(), 0),
                          Lender(second.back_end, 2, set(), 0)]

    exact = CoverageBounds(max_m=0.01, max_deg=1.0)   # only the same view covers
    borrower, pair = lenders()
    lendings = lend_from(borrower.back_end, pair, 0, views=exact)
    assert [lending.adopted for lending in lendings] == [len(archive), 0]
    assert pair[1].declined == {kf.id + offset: foreign_tag(1) | kf.id for kf in archive}
    # the first lender's copy of one view leaves the borrower: the second's is lent instead
    view = next(iter(archive)).id
    assert borrower.back_end.release_copies([foreign_tag(1) | view])
    lendings = lend_from(borrower.back_end, pair, 1, views=exact)
    assert [lending.adopted for lending in lendings] == [0, 1]
    assert foreign_tag(2) | (view + offset) in borrower.back_end.store
    assert view + offset not in pair[1].declined
    # every keyframe of both lenders without it
    borrower, pair = lenders()
    lendings = lend_from(borrower.back_end, pair, 0)
    assert [lending.adopted for lending in lendings] == [len(archive), len(archive)]


def test_the_edge_lends_a_place_s_view_once_within_its_bounds(room: Room) -> None:  # noqa: F811
    """The edge's lent_view_m and lent_view_deg reach the lending: with bounds that take in
    the whole room, the merged map adopts one of the first device's keyframes and declines
    the rest, round after round; without them (the default) it adopts all of them."""
    for bounds, adopted in ((CoverageBounds(10.0, 180.0), 1), (None, len(room[1]) + 1)):
        cores = _room_and_newcomer(room)
        merging = PlaceMerging(lambda: cores, background=False,  # noqa: B023
                               lend_in_view=False, lent_views=bounds)
        _walk_ar2_into_the_room(room, cores, merging)
        _tracked_at(cores["ar2"], 4, room[0].read(4).pose)   # type: ignore[attr-defined]
        assert merging.before_slot_end("ar2", 4) == (None, adopted, [])
        _tracked_at(cores["ar2"], 5, room[0].read(64).pose)  # type: ignore[attr-defined]
        assert merging.before_slot_end("ar2", 5) == (None, 0, [])
        assert merging.declined("ar2") == len(room[1]) + 1 - adopted
