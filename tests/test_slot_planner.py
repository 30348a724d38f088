"""The edge's slot planner: weights from id sets, policies on the edge's map, checked answers."""

from __future__ import annotations

import numpy as np
import pytest

from edge_mapper.slot_planner import FrameObservations, SlotConfig, SlotPlanner
from twinslam.policies.actions import ActionError, MapAction
from twinslam.policies.registry import make_policy
from twinslam.slam.back_end.keyframe_map import KeyFrameMap
from twinslam.slam.keyframe import as_track_ids
from twinslam.slot_protocol.lost_frame_rule import MIN_INLIERS


def _windows(n: int, rng: np.random.Generator) -> list[set[int]]:
    """Frame i observes 40 of the points 4i .. 4i+80 (a camera moving past them)."""
    return [set(rng.choice(np.arange(4 * i, 4 * i + 80), 40, replace=False).tolist())
            for i in range(n)]


def _setup(n_map: int = 12, n_slot: int = 20):
    rng = np.random.default_rng(0)
    sets = _windows(n_map + n_slot, rng)
    m = KeyFrameMap()
    point_of: dict[int, int] = {}
    for f in range(n_map):
        m.add_keyframe(f, np.eye(4))
        for p in sets[f]:
            if p not in point_of:
                point_of[p] = m.add_point(np.zeros(3), np.zeros(32, np.uint8))
            m.observe(f, point_of[p])
    frames = [FrameObservations(f, frozenset(point_of[p] for p in sets[f] if p in point_of),
                                frozenset(p for p in sets[f] if p not in point_of))
              for f in range(n_map, n_map + n_slot)]
    return m, frames, sets, point_of


def test_weights_count_shared_map_points_and_shared_tracks() -> None:
    m, frames, sets, point_of = _setup()
    planner = SlotPlanner(m, make_policy("lff"))
    by_id = {f.frame_id: f for f in frames}
    w = planner.weights(by_id, [11, 12, 13], [12, 13, 14])
    assert w[0, 0] == len(sets[11] & sets[12])                 # keyframe vs frame: map points
    assert w[1, 0] == 0                                        # an id with itself
    assert w[1, 1] == len(sets[12] & sets[13])                 # frames: map points + tracks
    assert w[2, 2] == len(sets[13] & sets[14])
    assert len(sets[13] & sets[14]) > len((sets[13] & sets[14]) & set(point_of))  # tracks count


@pytest.mark.parametrize("policy", ["lff", "pu", "adapt"])
def test_policies_plan_theorem1_sized_actions_on_the_edge_map(policy: str) -> None:
    m, frames, _, _ = _setup()
    planner = SlotPlanner(m, make_policy(policy), SlotConfig(vmax=14))
    plan = planner.plan(3, frames, rate_mbps=60.0, rate_state=1, rate_history=[0, 1])
    assert len(plan.action.upload) == 6                        # floor(60 · 0.5 / 5)
    assert len(plan.action.evict) == 12 + 6 - 14
    assert set(plan.action.upload) <= {f.frame_id for f in frames}
    assert plan.uncertainty is not None and 0 <= plan.uncertainty.lost_share < 1
    if policy == "lff":
        assert plan.action.upload == [26, 27, 28, 29, 30, 31]
        assert plan.action.evict == [0, 1, 2, 3]


def test_adapt_and_lff_differ_and_bad_actions_are_refused() -> None:
    m, frames, _, _ = _setup()
    lff = SlotPlanner(m, make_policy("lff"), SlotConfig(vmax=14)).plan(0, frames, 60.0, 1, [1])
    adapt = SlotPlanner(m, make_policy("adapt"), SlotConfig(vmax=14)).plan(0, frames, 60.0, 1,
                                                                           [1])
    assert (lff.action.upload, lff.action.evict) != (adapt.action.upload, adapt.action.evict)

    class Greedy:
        name = "bad"

        def decide(self, obs: object) -> MapAction:     # a deliberately broken policy
            return MapAction(list(obs.candidates), [])  # type: ignore[attr-defined]

    with pytest.raises(ActionError, match="slot 4: upload 20 distinct frames"):
        SlotPlanner(m, Greedy(), SlotConfig(vmax=14)).plan(4, frames, 60.0, 1, [1])
    with pytest.raises(ValueError, match="already keyframes"):
        SlotPlanner(m, make_policy("lff")).plan(5, [FrameObservations(3, frozenset())], 60.0, 1,
                                               [1])


def test_a_frame_sharing_fewer_map_points_than_the_device_needs_counts_as_lost() -> None:
    """The lost share is the share of the slot's frames that share fewer than the device's
    MIN_INLIERS map points with the map — counted against the map's points (tracks and
    points the map lacks never count), and with the keyframes still on their way; the plan
    tells each frame's count and verdict."""
    m, frames, _, _ = _setup(n_map=12, n_slot=30)
    in_map = set(m.points)
    expected = [len(f.map_points & in_map) < MIN_INLIERS for f in frames]
    assert 0 < sum(expected) < len(frames)              # the walk leaves the map
    plan = SlotPlanner(m, make_policy("lff"), SlotConfig(vmax=14)).plan(
        3, frames, rate_mbps=60.0, rate_state=1, rate_history=[0, 1])
    assert plan.uncertainty is not None
    assert plan.uncertainty.n_lost == sum(expected)
    # frame by frame, as a bench records them: the shared count and the rule's verdict
    assert list(plan.lost) == expected
    assert list(plan.shared) == [len(f.map_points & in_map) for f in frames]
    # a keyframe on its way (an open slot's upload) holds its frame's points for the map
    arriving = {frames[-1].frame_id + 100: FrameObservations(
        frames[-1].frame_id + 100, frames[0].map_points | {10**6 + i for i in range(40)},
        frozenset())}
    later = [FrameObservations(f.frame_id, f.map_points | {10**6 + i for i in range(40)},
                               f.tracks) for f in frames[-3:]]
    plan = SlotPlanner(m, make_policy("lff"), SlotConfig(vmax=14)).plan(
        4, later, rate_mbps=60.0, rate_state=1, rate_history=[0, 1], arriving=arriving)
    assert plan.uncertainty is not None and plan.uncertainty.n_lost == 0


def test_a_frames_keys_are_its_map_points_and_its_tracks_apart_read_only() -> None:
    """A frame's keys — read by the keyframe budget, the plan's weights and the slot's υ — are
    its map-point ids as they are and its track ids as negative keys (a track never counts as
    the map point of the same number), made once and shared read-only."""
    frame = FrameObservations(3, frozenset({5, 9}), frozenset(as_track_ids(np.array([5, 12]))))
    keys = frame.keys
    assert sorted(keys.tolist()) == [-13, -6, 5, 9]
    assert frame.keys is keys and not keys.flags.writeable
    with pytest.raises(ValueError):
        keys[0] = 1
    assert FrameObservations(4, frozenset(), frozenset()).keys.tolist() == []
