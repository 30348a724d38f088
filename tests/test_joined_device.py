"""A device whose map joined another device's place goes on at the edge's slot loop: its slot
open at the join finishes in the place's ids, its uploads tracked on its old map find their
points there, its next slots plan over its slice of the place's map, and the place's bundle
adjustment is run once, by the place's first device's core."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from edge_mapper.edge_core import EdgeConfig, EdgeMapperCore
from edge_mapper.slot_planner import SlotConfig
from tests.test_edge_core import Device, F, K
from twinslam.policies.registry import make_policy
from twinslam.slam.back_end.foreign_keyframes import TAG_SHIFT, foreign_tag, source_id
from twinslam.slam.back_end.map_back_end import BackEndConfig
from twinslam.slam.keyframe import TRACK_ID_BIT, KeyFramePayload

TAG = foreign_tag(1)
#: the second device's frame in the first's: it started 0.3 m along, turned 10° about y
ALIGNMENT = np.array([[np.cos(0.17), 0, np.sin(0.17), 0.3], [0, 1, 0, 0],
                      [-np.sin(0.17), 0, np.cos(0.17), 0], [0, 0, 0, 1]])


class Elsewhere(Device):
    """The first device's walk past the same wall, its poses told in a frame of its own until
    a map update moves what it holds into its place's (:attr:`frame`)."""

    frame = np.linalg.inv(ALIGNMENT)

    def keyframe(self, frame: int, slot: int, core: EdgeMapperCore) -> KeyFramePayload:
        data = super().keyframe(frame, slot, core)
        return dataclasses.replace(data, pose=self.frame @ data.pose)


def _core(restores: int = 0) -> EdgeMapperCore:
    return EdgeMapperCore(make_policy("lff"), K,
                          EdgeConfig(slot=SlotConfig(vmax=10), restore_keyframes=restores,
                                     back_end=BackEndConfig(ba_window=6)))


def _slot(core: EdgeMapperCore, device: Device, slot: int, version: int = -1):
    """Slot ``slot`` planned and its uploads made (not sent): (plan, uploads)."""
    told = getattr(device, "frame", np.eye(4))          # the frame its poses are told in
    frames = [dataclasses.replace(device.summary(f, core), map_version=version,
                                  pose=told @ device.pose(f))
              for f in range(slot * F, (slot + 1) * F)]
    plan = core.plan(slot, frames, 40.0, 0)
    return plan, [device.keyframe(f, slot, core) for f in plan.action.upload]


def _walk(core: EdgeMapperCore, device: Device, slots: range) -> None:
    for slot in slots:
        _, uploads = _slot(core, device, slot)
        for data in uploads:
            assert core.add_keyframe(data) is not None
        core.finish_slot(slot)


def test_a_joined_device_goes_on_in_its_places_map() -> None:
    first, second = _core(), _core()
    walker = Device(np.random.default_rng(0))
    other = Elsewhere(np.random.default_rng(1))          # corners of its own
    _walk(first, walker, range(3))
    _walk(second, other, range(3))
    own = set(second.map.keyframes)
    # its slot 3 is open at the join: planned on its own map (version 3), its uploads made
    plan, in_flight = _slot(second, other, 3, version=second.version)
    assert plan.action.upload and all(d.frame_id < 1 << TAG_SHIFT for d in in_flight)

    first_slice = first.slice.keyframe_ids()
    held = set(second.slice.point_ids().tolist())
    second.join_place(first, TAG, ALIGNMENT)
    assert second.map is first.map and not second.serves_place and first.serves_place
    assert second.slice.keyframe_ids() == sorted(TAG | k for k in own)
    assert first.slice.keyframe_ids() == first_slice
    assert second.version == 3

    reports = [second.add_keyframe(d) for d in in_flight]
    assert all(r is not None and not r.refused for r in reports)
    # its old map's points, named as its map version 3 named them, found in the place's
    assert all(r.associated + r.tracked > 0 for r in reports if r is not None)
    done = second.finish_slot(3)
    assert done.integrated == sorted(TAG | d.frame_id for d in in_flight)
    # its next map update tells the device the new id of every point it held (its
    # walls' own: none fused), once
    renamed = {p: q for p, q in done.tracks.items() if not p & TRACK_ID_BIT}
    assert renamed == {p: TAG | p for p in held} and renamed
    assert done.bundle_adjustment is None                 # the place's is the first's
    for data in in_flight:
        np.testing.assert_allclose(first.map.keyframes[TAG | data.frame_id].pose,
                                   ALIGNMENT @ data.pose, atol=1e-9)

    # its next slots, on the map update that moved it into the place's frame: asked for its
    # own frames, planned over its slice alone
    np.testing.assert_allclose(second.frame_correction_at(4), ALIGNMENT)
    other.frame = np.eye(4)
    for slot in (4, 5):
        plan, uploads = _slot(second, other, slot)
        assert plan.action.upload and \
            all(slot * F <= f < (slot + 1) * F for f in plan.action.upload)
        # its own keyframes (tagged) are no other device's: they cover none of its views
        assert not plan.covered
        for data in uploads:
            report = second.add_keyframe(data)
            assert report is not None and not report.refused and report.tracked > 0
        assert all(t & TRACK_ID_BIT for t in second.finish_slot(slot).tracks)
        assert len(second.slice.keyframes) <= second.slot_config.vmax
        assert all(source_id(k) != k for k in second.slice.keyframe_ids())
    _walk(first, walker, range(3, 6))
    assert first.slice.keyframe_ids() == sorted(k for k in first.map.keyframes
                                                if k < 1 << TAG_SHIFT)
    assert first.version == 6 and second.version == 6


def test_a_device_joins_a_place_once_and_only_without_checkpoints(tmp_path: Path) -> None:
    first, second = _core(), _core()
    _walk(first, Device(np.random.default_rng(0)), range(2))
    _walk(second, Elsewhere(np.random.default_rng(0)), range(2))
    with pytest.raises(ValueError, match="once"):
        second.join_place(second, TAG, ALIGNMENT)
    saved = EdgeMapperCore(make_policy("lff"), K, EdgeConfig(), tmp_path / "edge.npz")
    with pytest.raises(ValueError, match="checkpoints"):
        second.join_place(saved, TAG, ALIGNMENT)
    second.join_place(first, TAG, ALIGNMENT)
    with pytest.raises(ValueError, match="once"):
        second.join_place(first, foreign_tag(2), ALIGNMENT)
    with pytest.raises(ValueError, match="alone"):             # the place's map moves whole
        second.align(ALIGNMENT)


def test_a_joined_device_coming_where_the_place_was_mapped_takes_its_keyframes_in() -> None:
    # both walk past one wall: once joined, the second device's slice — given room to grow —
    # takes in keyframes the first device holds where its camera heads, as restores bring
    # archived ones back
    first, second = _core(restores=3), _core(restores=3)
    walker, other = Device(np.random.default_rng(0)), Elsewhere(np.random.default_rng(0))
    _walk(first, walker, range(4))
    second.map.next_point_id = 5000        # its map counts its points from elsewhere
    _walk(second, other, range(2))
    # its slot 2's summaries, sent before the join: they name its old map's points
    told = [dataclasses.replace(other.summary(f, second), map_version=second.version)
            for f in range(2 * F, 3 * F)]
    second.join_place(first, TAG, ALIGNMENT)
    # the corners both mapped are one point each now, the second device's tracks on them
    fused = set(second.ids.fused.values())
    assert len(fused) > 100 and all(p in first.map.points for p in fused)
    assert fused & set(second.local_mapping.track_points.values())
    # the summaries renamed once as they come in: an old point fused is the place's point,
    # and the plan over the resolved frames takes them as they are (renamed again, a fused
    # point's id would be taken for an old one)
    resolved = second.resolve_tracks(told)
    assert any(f.map_points & fused for f in resolved)
    held = set(second.slice.point_ids().tolist())
    plan = second.plan(2, resolved, 40.0, 0, tracks_resolved=True)
    assert plan.action.upload
    assert list(plan.shared) == [len(f.map_points & held) for f in resolved]
    second.finish_slot(2)
    other.frame = np.eye(4)
    second.set_vmax(20)
    _walk(second, other, range(3, 6))
    taken = [k for k in second.slice.keyframe_ids() if k < 1 << TAG_SHIFT]
    assert taken and all(first.slice.holds(k) or k in first.archive for k in taken)


def _turned(angle: float, shift: tuple[float, float, float]) -> np.ndarray:
    """A frame turned ``angle`` about y and shifted by ``shift`` in the first device's."""
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, 0, s, shift[0]], [0, 1, 0, shift[1]], [-s, 0, c, shift[2]],
                     [0, 0, 0, 1]])


def test_a_place_of_two_devices_joins_another_and_each_goes_on_in_it() -> None:
    # two places, two devices each: ar2 joined ar1's, ar4 joined ar3's; then ar3's place —
    # ar3's map with ar4's keyframes in it under ar4's tag — joins ar1's whole
    third_frame, fourth_frame = _turned(0.3, (-0.2, 0.0, 0.1)), _turned(-0.2, (0.15, 0.0, 0.0))
    first, second, third, fourth = _core(), _core(), _core(), _core()
    walker, other = Device(np.random.default_rng(0)), Elsewhere(np.random.default_rng(1))
    third_dev, fourth_dev = Elsewhere(np.random.default_rng(2)), Elsewhere(np.random.default_rng(3))
    third_dev.frame, fourth_dev.frame = np.linalg.inv(third_frame), np.linalg.inv(fourth_frame)
    for core, device in ((first, walker), (second, other), (third, third_dev),
                         (fourth, fourth_dev)):
        _walk(core, device, range(3))
    second.join_place(first, TAG, ALIGNMENT)
    # ar4's summaries sent on its own map, before either join
    before_both = [dataclasses.replace(fourth_dev.summary(f, fourth),
                                       map_version=fourth.version) for f in range(3 * F, 4 * F)]
    fourth_tag, third_tag = foreign_tag(3), foreign_tag(2)
    fourth.join_place(third, fourth_tag, np.linalg.inv(third_frame) @ fourth_frame)
    _walk(fourth, fourth_dev, range(3, 4))      # its slot open at the join, on its own map
    fourth_dev.frame = np.linalg.inv(third_frame)          # its map update moved it
    # ar4's slot 4 open at the second join: planned on ar3's place's map, its uploads made
    plan, in_flight = _slot(fourth, fourth_dev, 4, version=fourth.version)
    assert plan.action.upload
    third_keyframes = set(third.map.keyframes)

    with pytest.raises(ValueError, match="every device"):      # ar4 cannot stay behind
        third.join_place(first, third_tag, third_frame)
    third.join_place(first, third_tag, third_frame, [fourth])
    place = first.back_end
    assert all(core.back_end is place for core in (second, third, fourth))
    assert first.serves_place and not any(c.serves_place for c in (second, third, fourth))
    assert [d.tag for d in place.devices] == [0, TAG, third_tag, fourth_tag]
    # ar3's own keyframes take its tag, ar4's keep theirs; each where the truth has it
    assert set(place.map.keyframes) >= {k if k >> TAG_SHIFT else third_tag | k
                                        for k in third_keyframes}
    for device, core in ((third_dev, third), (fourth_dev, fourth)):
        own = core.slice.keyframe_ids()
        assert own and all(core.device.owns(k) for k in own)
        for k in own:
            truth = device.pose(source_id(k))
            assert np.linalg.norm(place.map.keyframes[k].pose[:3, 3] - truth[:3, 3]) < 0.05
    # ar4's summaries of its own map, renamed through both joins, name the points its
    # tracks became in the place's map (the summary it would send now names them too)
    now = [fourth_dev.summary(f, fourth) for f in range(3 * F, 4 * F)]
    renamed = fourth.resolve_tracks(before_both)
    kept = [f.map_points & place.map.points.keys() for f in renamed]
    assert sum(map(len, kept)) > 100 and \
        sum(map(len, kept)) >= 0.9 * sum(len(f.map_points) for f in renamed)
    assert all(k <= f.map_points for k, f in zip(kept, now, strict=True))
    # its uploads tracked between the joins find their points, in the place's frame
    reports = [fourth.add_keyframe(d) for d in in_flight]
    assert all(r is not None and not r.refused and r.associated + r.tracked > 0
               for r in reports)
    assert fourth.finish_slot(4).integrated == sorted(fourth_tag | d.frame_id
                                                      for d in in_flight)
    # every device goes on in the one place
    fourth_dev.frame = third_dev.frame = other.frame = np.eye(4)
    for core, device in ((first, walker), (second, other), (third, third_dev),
                         (fourth, fourth_dev)):
        _walk(core, device, range(5 if core is fourth else 3, 6))
        assert all(core.device.owns(k) or k in place.map.keyframes
                   for k in core.slice.keyframe_ids())
    assert first.version == 6 and fourth.version == 6
