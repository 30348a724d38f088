"""The edge's merging with ``merge_join``: where a device's keyframes are found in another
device's map, its map joins that place's — one map, one back end, the joining device's
keyframes under its tag in the place's frame, nothing lent — whose loop closer closes each
device's walk's loops as that walk's own; and a device leaving a joined place leaves the
others' map whole: what only it held goes to the place's archive, and a place whose first
device left is led by the next of its devices."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from rclpy.parameter import Parameter

from edge_mapper.edge_core import EdgeMapperCore
from edge_mapper.node import EdgeMapperNode
from edge_mapper.place_membership import source_of
from edge_mapper.place_merging import PlaceMerging
from tests.test_archive_relocalisation import room  # noqa: F401 (the archived room fixture)
from tests.test_edge_core import F, ReturningDevice
from tests.test_loop_closing import DriftingDevice, _edge
from tests.test_map_merging import (
    SECOND_IN_FIRST,
    Room,
    _core,
    _payload,
    _room_and_newcomer,
    _second_pose,
    _walk_ar2_into_the_room,
)
from twinslam.hosts.loopback import LoopbackDomain
from twinslam.node_runtime.node_main import NodeStartError
from twinslam.node_runtime.session import RosSession
from twinslam.rotations import rotation_angle_deg
from twinslam.slam.back_end.foreign_keyframes import (
    MAX_SOURCES,
    TAG_SHIFT,
    foreign_tag,
    source_id,
    tag_of,
)
from twinslam.slam.back_end.map_back_end import ClosedLoop
from twinslam.slam.back_end.pose_graph import WALK_ID_BITS

#: ar2's keyframes 10, 11, 12 are the room's frames 4, 64, 124
AR2_FRAMES = {10: 4, 11: 64, 12: 124}


def _joined(room: Room) -> tuple[dict[str, EdgeMapperCore], PlaceMerging]:  # noqa: F811
    """ar2 walked into ar1's room and its map joined ar1's place."""
    cores = _room_and_newcomer(room)
    merging = PlaceMerging(lambda: cores, background=False, join=True)
    events = _walk_ar2_into_the_room(room, cores, merging)
    assert events[:3] == [None, None, None] and events[3] is not None
    assert events[3].device == "ar2" and events[3].place == "ar1"
    return cores, merging


def test_a_later_device_joins_the_earlier_ones_map_and_borrows_nothing(
        room: Room) -> None:  # noqa: F811
    """ar2's map joins ar1's: one back end; ar2's keyframes are in it under ar2's tag, where
    the merge put them (the true frame to within centimetres); ar1's core runs the place's
    adjustment and loops, ar2's does not; neither looks any more, and no keyframe is lent —
    each is the place's own."""
    cores, merging = _joined(room)
    place = cores["ar1"].back_end
    assert cores["ar2"].back_end is place and merging.joined == {"ar2": "ar1"}
    assert cores["ar1"].serves_place and not cores["ar2"].serves_place
    tag = foreign_tag(source_of("ar2"))
    assert cores["ar2"].device.tag == tag
    for key, frame in AR2_FRAMES.items():
        pose = place.map.keyframes[tag | key].pose
        off = np.linalg.inv(SECOND_IN_FIRST @ _second_pose(room, frame)) @ pose
        assert np.linalg.norm(off[:3, 3]) < 0.03 and rotation_angle_deg(off[:3, :3]) < 0.5
    assert merging.others("ar1") == [] and merging.others("ar2") == []
    assert merging.before_slot_end("ar1", 4) == (None, 0, [])
    assert merging.before_slot_end("ar2", 4) == (None, 0, [])
    assert len(place.archive) == len(room[1]) and not merging.failures()


def test_two_places_of_two_devices_each_become_one_map(room: Room) -> None:  # noqa: F811
    """ar4's map joined ar1's place and ar3's joined ar2's; ar1 finds itself in ar2's map:
    the later place — ar2's map with ar3's keyframes in it — joins ar1's whole, by the
    inverse motion: ar2's keyframes, archived ones too, under ar2's tag, ar3's under their
    own, each where the merge puts them; every device of it told at its own slot end, and
    none of the four looks any more."""
    _, archive, _ = room
    cores = {name: _core() for name in ("ar1", "ar2", "ar3", "ar4")}
    for kf in archive:                                 # ar2's map of the room
        cores["ar2"].archive.add(kf)
    cores["ar2"].map.add_keyframe(999, archive.get(270).pose)
    cores["ar3"].map.add_keyframe(5, archive.get(270).pose)   # ar3's map, in ar2's frame
    cores["ar4"].map.add_keyframe(7, np.eye(4))               # ar4's, in ar1's
    for core in cores.values():
        core.back_end.device.k = room[0].intrinsics                    # type: ignore[attr-defined]
    merging = PlaceMerging(lambda: cores, background=False, join=True)
    for device, root in (("ar3", "ar2"), ("ar4", "ar1")):     # as merges before left them
        cores[device].join_place(cores[root], foreign_tag(source_of(device)), np.eye(4))
        merging.joined[device] = root
    assert merging.others("ar1") == ["ar2", "ar3"] and merging.others("ar2") == ["ar1", "ar4"]
    for slot, (key, frame) in enumerate(((10, 4), (11, 34), (12, 64), (13, 94), (14, 124))):
        cores["ar1"].map.add_keyframe(key, _second_pose(room, frame))
        merging.keyframe("ar1", _payload(room, frame, key))
        assert merging.take("ar1") is None
        merging.look("ar1", slot)
    assert merging.take("ar1") is None and not merging.failures()
    assert merging.joined == {"ar2": "ar1", "ar3": "ar1", "ar4": "ar1"}
    place = cores["ar1"].back_end
    assert all(core.back_end is place for core in cores.values())
    assert cores["ar1"].serves_place and not any(cores[d].serves_place
                                                 for d in ("ar2", "ar3", "ar4"))
    second, third = (foreign_tag(source_of(d)) for d in ("ar2", "ar3"))
    assert {d.tag for d in place.devices} == {0, second, third,
                                               foreign_tag(source_of("ar4"))}
    assert cores["ar2"].slice.keyframe_ids() == [second | 999]
    assert cores["ar3"].slice.keyframe_ids() == [third | 5]
    assert len(place.archive) == len(archive) and all(tag_of(kf.id) == second
                                                     for kf in place.archive)
    moved = np.linalg.inv(SECOND_IN_FIRST) @ archive.get(270).pose
    for kf_id in (second | 999, third | 5):
        off = np.linalg.inv(moved) @ place.map.keyframes[kf_id].pose
        assert np.linalg.norm(off[:3, 3]) < 0.03 and rotation_angle_deg(off[:3, :3]) < 0.5
    told = {d: merging.take(d) for d in ("ar2", "ar3", "ar4")}
    assert told["ar4"] is None
    assert (told["ar2"].place, told["ar2"].via) == ("ar1", "")         # type: ignore[union-attr]
    assert (told["ar3"].place, told["ar3"].via) == ("ar1", "ar2")      # type: ignore[union-attr]
    assert all(merging.others(d) == [] for d in cores)


def test_a_joined_device_that_leaves_hands_its_keyframes_to_the_places_archive(
        room: Room) -> None:  # noqa: F811
    """ar2 reclaimed (the edge serves it no more, then forgets it): the keyframes only it
    held leave the place's map for its archive, kept for ar1's restores; the place's back
    end has ar1's record alone again, and ar1 goes on as the place's first device."""
    cores, merging = _joined(room)
    place = cores["ar1"].back_end
    tag = foreign_tag(source_of("ar2"))
    held = sorted(cores["ar2"].slice.keyframes)
    assert held == sorted(tag | k for k in AR2_FRAMES)
    del cores["ar2"]                                  # the node drops the link first
    merging.forget("ar2")
    assert [k for k in place.map.keyframes if k in held] == []
    assert all(kf in place.archive for kf in held)
    assert place.devices == [place.device] and cores["ar1"].serves_place
    assert merging.joined == {} and merging.notices() == []


def test_a_place_whose_first_device_left_is_led_by_the_next_one(
        room: Room) -> None:  # noqa: F811
    """ar1, the place's first device, reclaimed: ar2 leads the place from now on — its core
    runs the place's adjustment, its looks look for other places, a newcomer looks in its
    map — and the log is told once; the keyframes only ar1 held go to the place's archive,
    and ar1's keyframes are still read with ar1's camera, though ar2's differs. Where the
    place joins another, its untagged ids take ar1's tag, not ar2's, which ar2's keyframes
    carry already."""
    cores, merging = _joined(room)
    place = cores["ar2"].back_end
    first_k = place.k.copy()
    cores["ar2"].device.k = first_k * [[1.1], [1.1], [1]]     # ar2's camera is another
    ar1_source = merging.source("ar1")
    held = [k for k in place.map.keyframes if not tag_of(k)]
    assert held
    del cores["ar1"]
    merging.forget("ar1")
    notices = merging.notices()
    assert len(notices) == 1 and "ar2 leads its place" in notices[0]
    assert merging.notices() == []
    assert cores["ar2"].serves_place and place.devices == [cores["ar2"].device]
    assert all(k in place.archive for k in held)
    np.testing.assert_array_equal(place.k, first_k)
    assert merging.joined == {} and merging.root("ar2") == "ar2"
    # ar3, served before ar2 in the edge's order now, walks into the room: ar2's place,
    # one device, the later served, joins ar3's
    ar2 = cores.pop("ar2")
    cores["ar3"] = _core()
    cores["ar3"].back_end.device.k = room[0].intrinsics                # type: ignore[attr-defined]
    cores["ar2"] = ar2
    merging.serve("ar3")
    assert merging.others("ar3") == ["ar2"] and merging.others("ar2") == ["ar3"]
    for slot, (key, frame) in enumerate(((10, 4), (11, 64), (12, 124))):
        cores["ar3"].map.add_keyframe(key, _second_pose(room, frame))
        merging.keyframe("ar3", _payload(room, frame, key))
        merging.take("ar3")
        merging.look("ar3", slot)
    merging.take("ar3")
    assert merging.joined == {"ar2": "ar3"} and not merging.failures()
    joined = cores["ar3"].back_end
    assert {tag_of(kf.id) for kf in joined.archive} == {foreign_tag(ar1_source)}
    assert {tag_of(k) for k in ar2.slice.keyframes} == {ar2.device.tag}
    assert ar2.device.tag == foreign_tag(source_of("ar2"))


def test_an_edge_that_joins_maps_refuses_to_start_with_checkpoints(
        tmp_path: Path, domain: LoopbackDomain, ros: RosSession) -> None:
    """``merge_join`` with a checkpoint path: the edge says why it cannot start (a joined
    place has no checkpoint file yet) instead of dropping the checkpoints silently."""
    with pytest.raises(NodeStartError, match=r"merge_join .* checkpoint"):
        EdgeMapperNode(context=ros.context, parameter_overrides=[
            Parameter("devices", value=["ar1", "ar2"]), Parameter("merge_maps", value=True),
            Parameter("merge_join", value=True),
            Parameter("checkpoint", value=str(tmp_path / "edge.npz"))])


def _walk_a_slot(core: EdgeMapperCore, device: ReturningDevice, slot: int
                 ) -> ClosedLoop | None:
    """Slot ``slot`` of ``device``'s walk at ``core``: planned, its uploads in, finished
    (the slot end takes the place's finished loop and starts its next job, whichever device
    of the place it is). The loop the slot took (None: none)."""
    plan = core.plan(slot, [device.summary(f, core) for f in range(slot * F, (slot + 1) * F)],
                     20.0, slot % 2)
    for f in plan.action.upload:
        assert core.add_keyframe(device.keyframe(f, slot, core)) is not None
    return core.finish_slot(slot).loop


def test_a_joined_devices_walk_closes_its_own_loop_as_it_would_alone() -> None:
    """A device whose map joined a place walks out and back along a wall, drifting on the
    way back, while the place's first device has no slots: the place's loop closer, run at
    the joined device's slot ends, looks for loops in its walk (its tag's keyframes) as in
    the first device's, and closes the loop the same walk closes alone, at the same slot —
    its keyframes put where they are alone, to the millimetre — while the first device's
    keyframe and frame stay where they were, and the joined device's frame moves with its
    walk's head."""
    alone, walker = _edge(loops=True), DriftingDevice(np.random.default_rng(3), 8 * F)
    place, joining = _edge(loops=True), _edge(loops=True)
    first = np.eye(4)
    first[:3, 3] = [0.0, 5.0, 0.0]                  # the first device's keyframe, far off
    place.map.add_keyframe(1, first)
    # the highest tag there is: its ids exceed a gtsam Symbol's index, as most devices' do
    tag = foreign_tag(MAX_SOURCES - 1)
    joining.join_place(place, tag, np.eye(4))
    joined = DriftingDevice(np.random.default_rng(3), 8 * F)
    for slot in range(16):
        loop = _walk_a_slot(alone, walker, slot)
        closed = _walk_a_slot(joining, joined, slot)
        if loop is not None:
            break
    assert loop is not None and not loop.refused and alone.loops_closed == 1
    assert closed is not None and not closed.refused and place.loops_closed == 1
    assert (tag_of(closed.old), tag_of(closed.new)) == (tag, tag)
    assert (source_id(closed.old), source_id(closed.new)) == (loop.old, loop.new)
    assert loop.moved_m > 0.1
    for k, kf in alone.map.keyframes.items():
        np.testing.assert_allclose(place.map.keyframes[tag | k].pose, kf.pose, atol=1e-3)
    np.testing.assert_allclose(place.map.keyframes[1].pose, first)
    np.testing.assert_allclose(place.frame_correction, np.eye(4))
    np.testing.assert_allclose(joining.frame_correction, alone.frame_correction, atol=1e-3)
    assert not np.allclose(joining.frame_correction, np.eye(4))


def test_a_walks_graph_keys_its_keyframes_by_the_bits_below_the_tags() -> None:
    """The loop graph keys a walk's keyframes by their ids below the device tag (one walk has
    one tag): the bits it keeps are the ones the tag leaves."""
    assert WALK_ID_BITS == TAG_SHIFT
