"""Views the map covers: a device in a place another device mapped does not upload a frame
a keyframe lent by that device stands beside; alone, it uploads as Theorem 1 says, unless its
own keyframes of an earlier visit are to cover its views too."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from edge_mapper.edge_core import EdgeConfig, EdgeMapperCore
from edge_mapper.parameters import PARAMETERS, edge_config
from edge_mapper.slot_planner import FrameObservations, SlotConfig, SlotPlan
from tests.test_edge_core import Device, F, K, _run
from twinslam.policies.registry import make_policy
from twinslam.slam.back_end.foreign_keyframes import foreign_tag
from twinslam.slam.back_end.view_coverage import (
    CoverageBounds,
    covered_views,
    uploads_for_new_views,
)
from twinslam.slot_protocol.lost_frame_rule import MIN_INLIERS
from twinslam.slot_protocol.map_entry import RESTORED, UPLOADED


def _pose(x: float, yaw_deg: float = 0.0) -> np.ndarray:
    pose = np.eye(4)
    a = np.radians(yaw_deg)
    pose[:3, :3] = [[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]]
    pose[0, 3] = x
    return pose


def test_a_keyframe_covers_a_frame_beside_it_looking_the_same_way() -> None:
    bounds = CoverageBounds(0.10, 10.0)
    frames = {1: _pose(0.0), 2: _pose(0.09), 3: _pose(0.12), 4: _pose(0.0, 9.0),
              5: _pose(0.0, 11.0), 6: _pose(0.0, 180.0)}
    assert covered_views(frames, [_pose(0.0)], bounds) == {1, 2, 4}
    # any keyframe may cover a frame: the second covers the third frame
    assert covered_views(frames, [_pose(0.0), _pose(0.2)], bounds) == {1, 2, 3, 4}
    assert covered_views(frames, [], bounds) == set()
    assert covered_views(frames, [_pose(0.0)], CoverageBounds(0.0, 10.0)) == set()
    with pytest.raises(ValueError, match=">= 0"):
        CoverageBounds(-0.1, 10.0)


def test_the_uplinks_count_goes_to_new_views_at_the_density_a_device_alone_spends_it() -> None:
    """Four uploads for thirty views: three new views ask for one, fifteen for two, sixteen
    for three (rounded up: any new view asks for one), none for none; never more than the new
    views, and the whole count where every view is new."""
    assert uploads_for_new_views(4, 3, 30) == 1
    assert uploads_for_new_views(4, 15, 30) == 2
    assert uploads_for_new_views(4, 16, 30) == 3
    assert uploads_for_new_views(8, 2, 30) == 1
    assert uploads_for_new_views(4, 0, 30) == 0
    assert uploads_for_new_views(0, 10, 30) == 0
    assert uploads_for_new_views(4, 30, 30) == 4
    assert uploads_for_new_views(4, 2, 2) == 2
    with pytest.raises(ValueError, match="at most the views"):
        uploads_for_new_views(4, 31, 30)


#: the walk's frames are 0.04 m apart: bounds of 0.10 m cover a few frames either side of a
#: keyframe, so the cases below tell a covered frame from its uncovered neighbour
WALL_BOUNDS = CoverageBounds(0.10, 10.0)


def _walked_edge() -> tuple[Device, EdgeMapperCore]:
    """Three slots of the wall walk (0.04 m a frame along x) integrated by an edge."""
    device = Device(np.random.default_rng(0))
    core = EdgeMapperCore(make_policy("lff"), K,
                          EdgeConfig(slot=SlotConfig(vmax=10), coverage=WALL_BOUNDS))
    _run(core, device, range(3), rates=[20.0])
    return device, core


def _posed_slot(device: Device, core: EdgeMapperCore, slot: int, version: int = -1
                ) -> list[FrameObservations]:
    """Slot ``slot``'s summaries with the device's poses, tracked on map ``version``."""
    return [dataclasses.replace(device.summary(f, core), pose=device.pose(f),
                                map_version=version)
            for f in range(slot * F, (slot + 1) * F)]


def _lend(core: EdgeMapperCore, keyframe_id: int, pose: np.ndarray,
          seeing: list[int] | None = None) -> None:
    """A keyframe another device uploaded, in this map (as a restore of an adopted one puts
    it), observing the points ``seeing`` (None: 30 of the map's newest keyframe's, where that
    keyframe measured them)."""
    core.map.add_keyframe(keyframe_id, pose)
    if seeing is None:
        newest = core.map.keyframes[max(k for k in core.map.keyframes if k < 2**40)]
        for point, (u, v, d) in list(newest.measurements.items())[:30]:
            core.map.observe(keyframe_id, point, (u, v), d)
        return
    for point in seeing:
        core.map.observe(keyframe_id, point, (320.0, 240.0), 2.0)


def test_a_slot_whose_views_lent_keyframes_cover_asks_for_no_upload() -> None:
    """Slot 3 (frames 24-31, 0.96-1.24 m) with another device's keyframes at 1.04 and 1.20 m:
    every frame is covered, nothing is asked for though the uplink carries two frames; the
    same keyframes as the device's own cover nothing (its own walk is no shared map), with
    one lent keyframe the uncovered frames are still asked for, as many as the uplink's count
    at the slot's density of views, and covered frames the map cannot serve (lost by the
    planner's rule) are too."""
    device, core = _walked_edge()
    for k, x in ((26, 1.04), (30, 1.20)):
        _lend(core, foreign_tag(0) | k, _pose(x))
    plan = core.plan(3, _posed_slot(device, core, 3), 20.0, 1)
    assert plan.action.upload == [] and plan.covered == frozenset(range(24, 32))

    device, core = _walked_edge()
    for k, x in ((26, 1.04), (30, 1.20)):
        _lend(core, 1000 + k, _pose(x))                  # the device's own ids
    plan = core.plan(3, _posed_slot(device, core, 3), 20.0, 1)
    assert len(plan.action.upload) == 2 and not plan.covered

    # one lent keyframe covers five of the eight views: the uplink's two uploads for eight
    # views become one for the three new ones, never a covered frame
    device, core = _walked_edge()
    _lend(core, foreign_tag(0) | 26, _pose(1.04))
    plan = core.plan(3, _posed_slot(device, core, 3), 20.0, 1)
    assert plan.covered == frozenset(range(24, 29))
    assert len(plan.action.upload) == 1 and not set(plan.action.upload) & plan.covered
    # one covering two of them: six new views ask for both
    device, core = _walked_edge()
    _lend(core, foreign_tag(0) | 23, _pose(0.92))
    plan = core.plan(3, _posed_slot(device, core, 3), 20.0, 1)
    assert plan.covered == frozenset({24, 25})
    assert len(plan.action.upload) == 2 and not set(plan.action.upload) & plan.covered

    # covered, but the device matched none of the map's points there: the map cannot serve
    # those frames (lost by the rule), so they are still asked for
    device, core = _walked_edge()
    for k, x in ((26, 1.04), (30, 1.20)):
        _lend(core, foreign_tag(0) | k, _pose(x))
    unmatched = [dataclasses.replace(f, map_points=frozenset(), tracks=frozenset())
                 for f in _posed_slot(device, core, 3)]
    plan = core.plan(3, unmatched, 20.0, 1)
    assert len(plan.action.upload) == 2 and not plan.covered

    device, core = _walked_edge()
    core.config = dataclasses.replace(core.config, coverage=CoverageBounds(0.0, 0.0))  # off
    for k, x in ((26, 1.04), (30, 1.20)):
        _lend(core, foreign_tag(0) | k, _pose(x))
    plan = core.plan(3, _posed_slot(device, core, 3), 20.0, 1)
    assert len(plan.action.upload) == 2 and not plan.covered


def _own_cover(after: int, entered: tuple[int, int], ahead: str = "map",
               points: int | None = None, lent: bool = False,
               min_points: int | None = None) -> SlotPlan:
    """Slot 3 planned with keyframes at 1.04 and 1.20 m beside its frames, and at 1.40 and
    1.56 m where the camera heads (in the map, in the ``archive``, or ``nowhere``), all the
    device's own with ``own_coverage_after_slots`` ``after``, having entered the map at
    ``entered`` (or all another device's, ``lent``); each frame reporting the first
    ``points`` of its map points (None: all); ``min_points``: the cover's margin (None: the
    default)."""
    device, core = _walked_edge()
    core.config = dataclasses.replace(core.config, own_coverage_after_slots=after)
    if min_points is not None:
        core.config = dataclasses.replace(core.config, coverage=dataclasses.replace(
            core.config.coverage, min_points=min_points))
    beside = ((26, 1.04), (30, 1.20))
    there = ((35, 1.40), (39, 1.56)) if ahead != "nowhere" else ()
    tag = foreign_tag(0) if lent else 1000          # 1000 + k: the device's own ids
    for k, x in (*beside, *there):
        _lend(core, tag | k if lent else tag + k, _pose(x))
        core.back_end.device.entered[tag + k] = entered
    if ahead == "archive":
        core.back_end.evict_to_archive([tag + k for k, _ in there], 0)
        assert all(tag + k in core.archive for k, _ in there)
    frames = _posed_slot(device, core, 3)
    if points is not None:
        assert all(len(f.map_points) >= points for f in frames)
        frames = [dataclasses.replace(f, map_points=frozenset(sorted(f.map_points)[:points]))
                  for f in frames]
    return core.plan(3, frames, 20.0, 1)


def test_a_devices_own_keyframes_of_an_earlier_visit_cover_its_views() -> None:
    """With ``own_coverage_after_slots`` 3, the device's own keyframes at 1.04 and 1.20 m
    cover slot 3's views (0.96-1.24 m) once they are views of an earlier visit — uploaded in
    slot 0, or restored from the archive whenever — and the camera heads where the device was
    before (1.40 and 1.56 m: keyframes there in the map, or in the archive, which restores
    bring in); not where it heads to new ground, not while they are the walk's last few
    slots (uploaded in slot 1), nor with the setting 0 (the paper's: a device alone uploads
    as Theorem 1 sizes it)."""
    for entered in ((0, UPLOADED), (2, RESTORED)):
        for ahead in ("map", "archive"):
            plan = _own_cover(3, entered, ahead)
            assert plan.covered == frozenset(range(24, 32)) and plan.action.upload == [], \
                (entered, ahead)
    for after, entered, ahead in ((3, (0, UPLOADED), "nowhere"), (3, (1, UPLOADED), "map"),
                                  (0, (0, UPLOADED), "map"), (0, (2, RESTORED), "map")):
        plan = _own_cover(after, entered, ahead)
        assert not plan.covered and len(plan.action.upload) == 2, (after, entered, ahead)


def test_a_cover_asks_the_map_to_serve_the_frame_with_the_margin_set() -> None:
    """Frames that match 20 of the map's points are served (above the device's tracking
    floor of 15) but thinly: with the default margin of 50 points, keyframes beside them —
    the device's own of an earlier visit, or another device's — leave them candidates and the
    uplink's count is asked for, where frames matching 50 are covered; with the margin at
    the floor they are covered too. The edge node's parameters start at the default."""
    assert edge_config({spec.name: spec.default for spec in PARAMETERS}).coverage == \
        CoverageBounds()
    assert CoverageBounds().min_points == 50 > MIN_INLIERS
    for lent in (False, True):
        thin = _own_cover(3, (0, UPLOADED), points=20, lent=lent)
        assert not thin.covered and len(thin.action.upload) == 2, lent
        served = _own_cover(3, (0, UPLOADED), points=50, lent=lent)
        assert served.covered == frozenset(range(24, 32)) and served.action.upload == [], lent
        floor = _own_cover(3, (0, UPLOADED), points=20, lent=lent, min_points=MIN_INLIERS)
        assert floor.covered == frozenset(range(24, 32)) and floor.action.upload == [], lent
    with pytest.raises(ValueError, match=">= 0"):
        CoverageBounds(min_points=-1)


def test_a_frame_tracked_before_a_merge_is_judged_where_the_merge_put_it() -> None:
    """After the map moved 2 m along x (a merge's alignment), a frame the device tracked on
    the map before it is 2 m further along in the map's frame now: a lent keyframe there
    covers it, one where its pose says (in the frame it left) does not."""
    device, core = _walked_edge()
    before = core.version
    core.back_end.align(_pose(2.0))
    core.version += 1
    _lend(core, foreign_tag(0) | 26, _pose(2.0 + 1.04))
    _lend(core, foreign_tag(0) | 30, _pose(2.0 + 1.20))
    plan = core.plan(3, _posed_slot(device, core, 3, version=before), 20.0, 1)
    assert plan.covered == frozenset(range(24, 32))
    # the same poses said to be in the map's frame now are 2 m from the lent keyframes
    device, core = _walked_edge()
    core.back_end.align(_pose(2.0))
    core.version += 1
    _lend(core, foreign_tag(0) | 26, _pose(2.0 + 1.04))
    plan = core.plan(3, _posed_slot(device, core, 3, version=core.version), 20.0, 1)
    assert not plan.covered and len(plan.action.upload) == 2


def test_a_frame_that_tracks_on_a_lent_keyframes_points_is_covered_wherever_it_stands() -> None:
    """Another device's keyframe 2 m off and turned away, out of the pose bounds, seeing the
    points slot 3's frames track on: with ``by_points`` every frame shares the cover's 50 of
    its reported points with it, all are covered and the slot asks for nothing; off (the
    default), the keyframe covers nothing there; the device's own keyframe seeing the same
    points covers nothing either (its own walk is no shared map). Where the keyframe sees 45
    of the points every frame of the slot sees and those only the first frames see, the
    frames that share 50 are covered and the two that share fewer ask for the upload."""
    by_points, pose_only = (dataclasses.replace(WALL_BOUNDS, by_points=b) for b in (True, False))
    assert not CoverageBounds().by_points
    for bounds, lent in ((by_points, True), (pose_only, True), (by_points, False)):
        device, core = _walked_edge()
        core.config = dataclasses.replace(core.config, coverage=bounds)
        frames = _posed_slot(device, core, 3)
        seen = sorted(set().union(*(f.map_points for f in frames)))
        _lend(core, (foreign_tag(0) | 99) if lent else 1099, _pose(3.0, 90.0), seen)
        plan = core.plan(3, frames, 20.0, 1)
        if bounds.by_points and lent:
            assert plan.covered == frozenset(range(24, 32)) and plan.action.upload == []
        else:
            assert not plan.covered and len(plan.action.upload) == 2, (bounds, lent)

    device, core = _walked_edge()
    core.config = dataclasses.replace(core.config, coverage=by_points)
    frames = _posed_slot(device, core, 3)
    every = frozenset.intersection(*(f.map_points for f in frames))
    first_only = frames[0].map_points - every
    _lend(core, foreign_tag(0) | 99, _pose(3.0, 90.0),
          sorted(every)[:45] + sorted(first_only))
    shares = [len(f.map_points & (set(sorted(every)[:45]) | first_only)) for f in frames]
    assert min(shares[:6]) >= 50 > max(shares[6:])
    plan = core.plan(3, frames, 20.0, 1)
    assert plan.covered == frozenset(range(24, 30))
    assert len(plan.action.upload) == 1 and set(plan.action.upload) <= {30, 31}
