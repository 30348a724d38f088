"""A decision that keeps the edge's map one graph: the policy's stands unless it would leave
the map in more pieces; then the newest frames that tie to the map go up, and keyframes whose
eviction splits nothing leave."""

from __future__ import annotations

import numpy as np

from edge_mapper.slot_planner import FrameObservations, SlotConfig, SlotPlanner
from twinslam.policies.actions import MapAction, SlotObservation
from twinslam.policies.connected_map import (
    MIN_TIE,
    connected_action,
    mended_decision,
    pieces,
    seen_keyframes,
)
from twinslam.policies.registry import make_policy
from twinslam.slam.back_end.keyframe_map import KeyFrameMap


def _observation(sets: dict[int, set[int]], map_frames: list[int], candidates: list[int],
                 n_upload: int) -> SlotObservation:
    """A slot whose keyframes and frames observe ``sets`` (weights: shared ids)."""
    def weights(a: list[int], b: list[int]) -> np.ndarray:
        return np.array([[0 if x == y else len(sets[x] & sets[y]) for y in b] for x in a])
    return SlotObservation(7, map_frames, candidates, n_upload, 0, 40.0, 0, [0], 2, weights)


def _span(lo: int, hi: int) -> set[int]:
    return set(range(lo, hi + 1))


def _turning_slot() -> tuple[dict[int, set[int]], SlotObservation]:
    """Two keyframes (10, 11); a slot whose frames turn away from them: 20 sees 21 of
    keyframe 11's points, 21 only 11 of them (fewer than a tie), 23 sees 15 of 20's and
    nothing of the map, and the newest two (24, 25) see only 23's side."""
    sets = {10: _span(1, 50), 11: _span(30, 80), 20: _span(60, 100), 21: _span(70, 120),
            23: _span(86, 140), 24: _span(120, 170), 25: _span(125, 175)}
    return sets, _observation(sets, [10, 11], [20, 21, 23, 24, 25], 2)


def test_uploads_that_would_add_a_piece_of_their_own_give_way_to_frames_tied_to_the_map(
        ) -> None:
    """A fast turn: the policy's newest two frames share nothing with the map. The mended
    uploads are the newest frame tied to the map (20; 21's 11 points are no tie) and then the
    newest tied to it (23): the map stays one graph, the upload count is the policy's."""
    sets, obs = _turning_slot()
    assert len(sets[21] & sets[11]) < MIN_TIE <= len(sets[20] & sets[11])
    lff = MapAction([24, 25], [])
    mended = connected_action(obs, lff)
    assert mended.upload == [20, 23]
    assert mended.evict == [] and mended.restore == []
    graph = obs.weight_block([10, 11, *mended.upload], [10, 11, *mended.upload])
    assert pieces(graph) == 1
    assert pieces(obs.weight_block([10, 11, 24, 25], [10, 11, 24, 25])) == 2


def test_uploads_that_join_the_map_are_left_as_the_policy_chose_them() -> None:
    """Any choice whose frames join the map is the policy's to make, tied or not by
    MIN_TIE (21 shares 11 points with it): the very action object comes back."""
    _, obs = _turning_slot()
    for upload in ([20, 21], [21, 23], [20, 23]):
        action = MapAction(upload, [])
        assert connected_action(obs, action) is action
    # 25 sees neither the map nor 20: that choice is mended
    assert connected_action(obs, MapAction([20, 25], [])).upload == [20, 23]


def test_where_no_frame_ties_to_the_map_the_policys_choice_stands() -> None:
    """A slot that saw nothing of the map (a device lost, then tracking anew): there is no
    tie to mend with, and the policy's uploads go."""
    sets = {10: _span(1, 50), 11: _span(30, 80), 20: _span(500, 560), 21: _span(520, 580),
            22: _span(540, 600)}
    obs = _observation(sets, [10, 11], [20, 21, 22], 2)
    action = MapAction([21, 22], [])
    assert connected_action(obs, action) is action


def test_an_eviction_that_would_cut_the_map_gives_way_to_one_that_splits_nothing() -> None:
    """Keyframe 11 is the only tie between 10 and 12; the policy evicts it, and the next
    keyframe in the order the map's keyframes entered it that splits nothing (10, an end of
    the chain) goes instead. The count is the policy's."""
    sets = {10: _span(1, 50), 11: _span(40, 90), 12: _span(80, 130), 20: _span(100, 150),
            21: _span(110, 160)}
    obs = _observation(sets, [10, 11, 12], [20, 21], 1)
    obs.n_evict = 1
    obs.entered = [11, 10, 12]
    mended = connected_action(obs, MapAction([21], [11]))
    assert mended == MapAction([21], [10])
    assert "evicts [10] instead of the policy's [11]" in mended_decision(
        MapAction([21], [11]), mended)
    assert "evicts [keyframe 10] instead of the policy's [keyframe 11]" in mended_decision(
        MapAction([21], [11]), mended, lambda k: f"keyframe {k}")


def test_an_island_may_go_and_a_map_in_pieces_is_not_made_worse() -> None:
    """Keyframe 12 shares nothing with 10 and 11 (the map is in two pieces already):
    evicting 10 leaves two pieces, as many as before, and stands."""
    sets = {10: _span(1, 50), 11: _span(30, 80), 12: _span(300, 350), 20: _span(60, 100)}
    obs = _observation(sets, [10, 11, 12], [20], 1)
    action = MapAction([20], [10])
    assert connected_action(obs, action) is action
    assert connected_action(obs, MapAction([20], [12])) == MapAction([20], [12])


def test_uploads_that_tie_only_to_an_evicted_keyframe_keep_it_in_the_map() -> None:
    """The map less its evictions is what the uploads must join: frame 22 sees only keyframe
    11, which the policy evicts; 11 stays and the next keyframe that splits nothing (10) goes."""
    sets = {10: _span(1, 50), 11: _span(30, 80), 12: _span(40, 60), 22: _span(70, 110)}
    obs = _observation(sets, [10, 11, 12], [22], 1)
    assert connected_action(obs, MapAction([22], [12])) == MapAction([22], [12])
    assert connected_action(obs, MapAction([22], [11])) == MapAction([22], [10])


def _turning_map() -> tuple[KeyFrameMap, list[FrameObservations]]:
    """An edge map of two keyframes and a slot of 30 frames turning away from them: frame i
    sees points 4i .. 4i + 80 (a camera panning past them), the map's keyframes frames 0-1."""
    m = KeyFrameMap()
    point_of: dict[int, int] = {}
    for f in range(2):
        m.add_keyframe(f, np.eye(4))
        for p in range(4 * f, 4 * f + 81):
            if p not in point_of:
                point_of[p] = m.add_point(np.zeros(3), np.zeros(32, np.uint8))
            m.observe(f, point_of[p])
    frames = [FrameObservations(f, frozenset(point_of[p] for p in range(4 * f, 4 * f + 81)
                                             if p in point_of),
                                frozenset(p for p in range(4 * f, 4 * f + 81)
                                          if p not in point_of))
              for f in range(2, 32)]
    return m, frames


def test_the_edge_plans_uploads_that_keep_its_map_one_graph_unless_told_not_to() -> None:
    """The edge's planner with LFF: the slot's newest frames (30, 31) have panned past the
    map, and the plan uploads the newest frame that still sees it and the newest that sees
    that one instead; with ``connected_map`` off, LFF's newest two as they are."""
    m, frames = _turning_map()
    on = SlotPlanner(m, make_policy("lff"), SlotConfig(vmax=45)).plan(
        1, frames, rate_mbps=20.0, rate_state=0, rate_history=[0])
    off = SlotPlanner(m, make_policy("lff"), SlotConfig(vmax=45, connected_map=False)
                      ).plan(1, frames, rate_mbps=20.0, rate_state=0, rate_history=[0])
    assert off.action.upload == [30, 31] and off.policy_action is None
    # frame 21 sees points 84 .. 164 and the map holds 0 .. 84: one shared point is no tie;
    # frame 20 shares 5 points, 18 shares 13, 17 shares 17 (the newest with MIN_TIE); then
    # the newest frame sharing MIN_TIE with frame 17 (points 68 .. 148)
    # the map holds points 0 .. 84: frame 17 shares 17 of them (MIN_TIE: 15), frame 18 only
    # 13; frame 31 (points 124 .. 204) shares 25 tracks with frame 17 (68 .. 148)
    assert on.action.upload == [17, 31]
    assert on.policy_action is not None and on.policy_action.upload == [30, 31]
    assert mended_decision(on.policy_action, on.action).startswith(
        "uploads [17, 31] instead of the policy's [30, 31]")


def _map_in_two_pieces() -> tuple[dict[int, set[int]], SlotObservation]:
    """Keyframes 10-11 (points 1-80) and 12-14 (points 300-420, a chain: 12 ties to 13, 13 to
    14) share nothing: the map is in two pieces. The slot's frames 20-21 see only the second
    piece (keyframe 14's points)."""
    sets = {10: _span(1, 50), 11: _span(30, 80), 12: _span(300, 350), 13: _span(330, 390),
            14: _span(370, 420), 20: _span(380, 440), 21: _span(400, 460)}
    return sets, _observation(sets, [10, 11, 12, 13, 14], [20, 21], 1)


def test_a_piece_the_camera_left_leaves_the_map_whole_beyond_the_count() -> None:
    """No tracked frame has tied to keyframes 10-11 for STALE_SLOTS slots: their piece goes
    whole with the slot's decision, though Theorem 1 asked for no eviction, and the map left
    is one graph: the piece the camera is in with the upload."""
    _, obs = _map_in_two_pieces()
    action = MapAction([21], [])
    mended = connected_action(obs, action, stale={10, 11})
    assert mended == MapAction([21], [10, 11])
    kept = [12, 13, 14, 21]
    assert pieces(obs.weight_block(kept, kept)) == 1
    said = mended_decision(action, mended)
    assert "evicts [10, 11] instead of the policy's []" in said
    assert said.endswith("no tracked frame tied to these for 2 slots: the map keeps the piece "
                         "the camera is in")
    # the same map while the piece is not stale yet (the camera may look back): as chosen
    assert connected_action(obs, action) is action
    assert connected_action(obs, action, stale={10}) is action


def test_a_dropped_piece_counts_towards_the_evictions_the_uploads_need() -> None:
    """Theorem 1 asks for two evictions; the stale piece makes room for both, and the piece
    the camera is in keeps the keyframes the policy would have evicted. With three asked
    for, the policy's first eviction in the live piece goes as well; a decision that evicts
    the piece itself stands."""
    _, obs = _map_in_two_pieces()
    obs.n_evict = 2
    assert connected_action(obs, MapAction([21], [12, 10]), stale={10, 11}) == \
        MapAction([21], [10, 11])
    obs.n_evict = 3
    assert connected_action(obs, MapAction([21], [12, 13, 10]), stale={10, 11}) == \
        MapAction([21], [10, 11, 12])
    whole = MapAction([21], [12, 10, 11])
    assert connected_action(obs, whole, stale={10, 11}) is whole


def test_no_piece_is_dropped_that_an_upload_joins_or_where_nothing_would_be_left() -> None:
    """An upload that ties the stale piece to the rest makes the map one graph: nothing is
    dropped. A map all of whose keyframes are stale (a device that tied to nothing, its
    uploads none) stays, for the edge to relocalise the device in."""
    sets, obs = _map_in_two_pieces()
    sets[22] = _span(60, 100) | _span(400, 430)      # sees keyframe 11 and keyframe 14
    obs = _observation(sets, [10, 11, 12, 13, 14], [20, 21, 22], 1)
    bridging = MapAction([22], [])
    assert connected_action(obs, bridging, stale={10, 11}) is bridging
    _, obs = _map_in_two_pieces()
    obs.n_upload = 0
    nothing = MapAction([], [])
    assert connected_action(obs, nothing, stale={10, 11, 12, 13, 14}) is nothing


def test_the_edge_drops_a_piece_no_frame_has_tied_to_for_two_slots() -> None:
    """The edge's planner over a map in two pieces whose slot frames see only the second:
    the first two slots keep the piece behind the camera (it was tied to when it entered; one
    slot away may be a glance), the third evicts it whole; a tracked frame that ties to it
    again keeps it another two slots."""
    m = KeyFrameMap()
    point_of: dict[int, int] = {}
    for kf, points in ((0, range(0, 60)), (1, range(30, 90)), (2, range(500, 560)),
                       (3, range(530, 590))):
        m.add_keyframe(kf, np.eye(4))
        for p in points:
            if p not in point_of:
                point_of[p] = m.add_point(np.zeros(3), np.zeros(32, np.uint8))
            m.observe(kf, point_of[p])
    planner = SlotPlanner(m, make_policy("lff"), SlotConfig(vmax=45))

    def slot(k: int, first: int, sees: range) -> MapAction:
        frames = [FrameObservations(first + i, frozenset(point_of[p] for p in sees))
                  for i in range(4)]
        return planner.plan(k, frames, rate_mbps=20.0, rate_state=0,
                            rate_history=[0]).action

    assert slot(1, 10, range(540, 590)).evict == []
    assert slot(2, 20, range(540, 590)).evict == []
    assert slot(3, 30, range(540, 590)).evict == [0, 1]
    assert slot(4, 40, range(20, 60)).evict == []          # the camera back at keyframes 0-1
    assert slot(5, 50, range(540, 590)).evict == []
    assert slot(6, 60, range(540, 590)).evict == [0, 1]


def test_a_keyframe_is_seen_where_a_frame_ties_to_any_keyframe_of_its_piece() -> None:
    """Keyframes 0-1-2 a chain, 3-4 a second piece: a frame sharing MIN_TIE points with
    keyframe 2 sees the whole chain (0 through its piece), a frame sharing fewer with keyframe
    4 sees nothing of the other piece."""
    w = np.zeros((5, 5))
    for a, b in ((0, 1), (1, 2), (3, 4)):
        w[a, b] = w[b, a] = 40
    frames = np.zeros((2, 5))
    frames[0, 2] = MIN_TIE
    frames[1, 4] = MIN_TIE - 1
    assert seen_keyframes(w, frames).tolist() == [True, True, True, False, False]
    assert seen_keyframes(w, np.zeros((0, 5))).tolist() == [False] * 5
    assert seen_keyframes(np.zeros((0, 0)), np.zeros((0, 0))).tolist() == []
