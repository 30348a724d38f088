"""Closing a loop with a pose graph: a walk round a room that drifts comes back to where it
started; the loop measured between its first and last keyframe takes the drift out of every
keyframe, and each point moves with its keyframe. A walk tied to another device's keyframes
follows them where that device's loop moved them."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from twinslam.slam.back_end.foreign_keyframes import MAX_SOURCES, foreign_tag
from twinslam.slam.back_end.pose_graph import (
    ANCHOR_SHARED_MIN,
    Anchors,
    LoopEdge,
    close_loop,
    follow_anchors,
    move_with_keyframes,
    step_sigmas,
)

#: how much too far each step of a drifting walk turns: a tracker's steps err by about this
#: (a step of this room's walk, 0.31 m and 9°, is trusted to 0.3°)
DRIFT = math.radians(0.2)


def _yaw(angle: float, x: float = 0.0, y: float = 0.0) -> np.ndarray:
    pose = np.eye(4)
    c, s = math.cos(angle), math.sin(angle)
    pose[:2, :2] = [[c, -s], [s, c]]
    pose[:2, 3] = x, y
    return pose


def _walk(n: int, drift_rad: float, per_lap: int | None = None
          ) -> tuple[dict[int, np.ndarray], dict[int, np.ndarray]]:
    """(truth, estimate): ``n`` keyframes on a circle of 2 m, ``per_lap`` of them a lap
    (default ``n``: the last one back beside the first); the estimate chains the true steps,
    each turned by ``drift_rad`` too far."""
    lap = per_lap or n
    truth = {i: _yaw(2 * math.pi * i / lap, 2 * math.cos(2 * math.pi * i / lap),
                     2 * math.sin(2 * math.pi * i / lap)) for i in range(n)}
    estimate = {0: truth[0].copy()}
    for i in range(1, n):
        estimate[i] = _drifted_step(estimate[i - 1], truth, i, drift_rad)
    return truth, estimate


def _drifted_step(previous: np.ndarray, truth: dict[int, np.ndarray], i: int,
                  drift_rad: float) -> np.ndarray:
    """Keyframe ``i``'s estimate: the true step from ``i - 1`` chained onto ``previous``,
    turned ``drift_rad`` too far."""
    return previous @ np.linalg.inv(truth[i - 1]) @ truth[i] @ _yaw(drift_rad)


def _largest_error(poses: dict[int, np.ndarray], truth: dict[int, np.ndarray]) -> float:
    return max(float(np.linalg.norm(poses[i][:3, 3] - truth[i][:3, 3])) for i in truth)


def test_a_loop_with_a_known_drift_is_closed_and_the_drift_removed() -> None:
    truth, estimate = _walk(40, DRIFT)
    drifted = _largest_error(estimate, truth)
    assert drifted > 0.25                                 # the walk ends ~0.3 m off
    measured = np.linalg.inv(truth[0]) @ truth[39]        # the geometric check's answer
    closed = close_loop(estimate, 0, 39, measured)
    assert closed.final_error < 0.1 * closed.initial_error     # under the loop's Cauchy loss
    assert _largest_error(closed.poses, truth) < 0.1 * drifted
    np.testing.assert_allclose(closed.poses[0], estimate[0], atol=1e-5)    # the gauge
    # the loop itself closes to what was measured
    np.testing.assert_allclose(np.linalg.inv(closed.poses[0]) @ closed.poses[39], measured,
                               atol=0.02)
    # a point seen from the last keyframe moves with it, one of the first stays
    point = estimate[39][:3, 3] + [0.0, 0.0, 1.0]
    moved = move_with_keyframes(np.array([point, np.zeros(3)]), np.array([39, 0]),
                                closed.corrections)
    c = closed.corrections[39]
    np.testing.assert_allclose(moved[0], c[:3, :3] @ point + c[:3, 3])
    np.testing.assert_allclose(moved[1], np.zeros(3), atol=1e-5)


def test_a_walk_without_drift_is_left_where_it_is() -> None:
    truth, estimate = _walk(20, 0.0)
    closed = close_loop(estimate, 0, 19, np.linalg.inv(truth[0]) @ truth[19])
    assert _largest_error(closed.poses, truth) < 1e-6


def test_a_loop_measured_on_more_matches_weighs_more() -> None:
    """Two measurements of one loop 3 cm apart (a fit's noise): the graph ends nearer the one
    measured on 400 matches than the one measured on 50, whichever was closed first."""
    _, estimate = _walk(20, 0.0)
    a = np.linalg.inv(estimate[0]) @ estimate[19] @ _yaw(0.0, 0.03)
    b = np.linalg.inv(estimate[0]) @ estimate[19] @ _yaw(0.0, -0.03)

    def lands(poses: dict[int, np.ndarray]) -> float:
        """Where the closed loop puts keyframe 19 along its x: +3 cm is a, −3 cm is b."""
        walked = np.linalg.inv(estimate[0]) @ estimate[19]
        return float((np.linalg.inv(walked) @ np.linalg.inv(poses[0]) @ poses[19])[0, 3])

    b_stronger = close_loop(estimate, 0, 19, b, earlier=[LoopEdge(0, 19, a, 50)], inliers=400)
    a_stronger = close_loop(estimate, 0, 19, b, earlier=[LoopEdge(0, 19, a, 400)], inliers=50)
    assert lands(b_stronger.poses) < -0.01 and lands(a_stronger.poses) > 0.01


def test_a_loop_must_join_two_keyframes_of_the_graph() -> None:
    _, estimate = _walk(5, 0.0)
    with pytest.raises(ValueError, match="two keyframes"):
        close_loop(estimate, 0, 7, np.eye(4))
    with pytest.raises(ValueError, match="two keyframes"):
        close_loop(estimate, 3, 3, np.eye(4))


def test_a_second_loop_holds_the_first() -> None:
    """Two laps of the room, each drifting: the first lap's loop (0 → 39) is closed, then the
    second lap comes past keyframe 20 again (60). Its graph holds the first loop too, so the
    first lap stays closed (within 1 cm); a graph made of the new loop alone spreads the
    second lap's drift over the first lap's steps and opens it again."""
    drift = DRIFT
    truth, estimate = _walk(80, drift, per_lap=40)
    first = LoopEdge(0, 39, np.linalg.inv(truth[0]) @ truth[39])
    lap = {i: p for i, p in estimate.items() if i < 40}
    closed = close_loop(lap, first.old, first.new, first.measured).poses
    # the second lap continues from the corrected first one, drifting as before
    for i in range(40, 80):
        closed[i] = _drifted_step(closed[i - 1], truth, i, drift)
    second = np.linalg.inv(truth[20]) @ truth[60]

    def first_lap_gap(poses: dict[int, np.ndarray]) -> float:
        relative = np.linalg.inv(poses[0]) @ poses[39]
        return float(np.linalg.norm(relative[:3, 3] - first.measured[:3, 3]))

    assert first_lap_gap(closed) < 0.02
    held = close_loop(closed, 20, 60, second, earlier=[first]).poses
    alone = close_loop(closed, 20, 60, second).poses
    assert first_lap_gap(held) < 0.01
    assert first_lap_gap(alone) > 0.03
    # both close the second loop
    for poses in (held, alone):
        relative = np.linalg.inv(poses[20]) @ poses[60]
        assert np.linalg.norm(relative[:3, 3] - second[:3, 3]) < 0.05


def test_keyframes_that_see_one_place_move_together() -> None:
    """The walk goes round the room and on past where it started (30 keyframes a lap):
    keyframes 5 and 35 stand at one place and share many points. The loop's correction moves
    the two alike, where without the covisibility factor the correction spread over the
    thirty steps between them pulls them apart."""
    truth, estimate = _walk(40, DRIFT, per_lap=30)
    measured = np.linalg.inv(truth[0]) @ truth[39]
    shared = {(a, a + 1): 150 for a in range(39)}

    def apart(poses: dict[int, np.ndarray]) -> np.ndarray:
        return np.linalg.inv(poses[5]) @ poses[35]

    before = apart(estimate)
    together = close_loop(estimate, 0, 39, measured, {**shared, (5, 35): 400}).poses
    loose = close_loop(estimate, 0, 39, measured, shared).poses
    held = np.linalg.norm(apart(together)[:3, 3] - before[:3, 3])
    pulled = np.linalg.norm(apart(loose)[:3, 3] - before[:3, 3])
    assert held < 0.1 * pulled


def test_a_wrong_loop_pulls_with_a_bounded_force(monkeypatch: pytest.MonkeyPatch) -> None:
    """The walk round the room closed by two true loops (0 → 39, 1 → 38) and a wrong one (0 →
    39 measured 1 m off: a look-alike that got through): under the loops' Cauchy loss the true
    loops hold and the last keyframe ends within 10 cm of the truth; as plain least squares
    (the kernel made wide) the wrong loop drags it a third of a metre."""
    truth, estimate = _walk(40, DRIFT)
    true_loops = [LoopEdge(1, 38, np.linalg.inv(truth[1]) @ truth[38])]
    wrong = LoopEdge(0, 39, np.linalg.inv(truth[0]) @ truth[39] @ _yaw(0.0, 1.0, 0.0))
    measured = np.linalg.inv(truth[0]) @ truth[39]

    def last_error() -> float:
        poses = close_loop(estimate, 0, 39, measured, earlier=[*true_loops, wrong]).poses
        return float(np.linalg.norm(poses[39][:3, 3] - truth[39][:3, 3]))

    robust = last_error()
    monkeypatch.setattr("twinslam.slam.back_end.pose_graph.LOOP_CAUCHY", 1e9)
    plain = last_error()
    assert robust < 0.1 and plain > 0.25, (robust, plain)


def test_a_long_step_takes_more_of_the_correction_than_a_short_one() -> None:
    """A straight walk of 0.1 m steps with one step of 1 m in the middle (the camera moved on
    between two uploads), 5 cm short at its end: the loop's correction lengthens the long
    step most — a tracker errs by a share of the way it went, and the graph trusts a step
    as much (:func:`step_sigmas`)."""
    lengths = [0.1] * 5 + [1.0] + [0.1] * 5
    truth = {0: np.eye(4)}
    for i, length in enumerate(lengths, start=1):
        truth[i] = truth[i - 1] @ _yaw(0.0, length)
    estimate = {i: p @ _yaw(0.0, -0.05 * i / len(lengths)) for i, p in truth.items()}
    closed = close_loop(estimate, 0, len(lengths), np.linalg.inv(truth[0]) @ truth[len(lengths)])

    def grown(i: int) -> float:
        """How much longer step i → i + 1 became."""
        def step(poses: dict[int, np.ndarray]) -> float:
            return float(np.linalg.norm((np.linalg.inv(poses[i]) @ poses[i + 1])[:3, 3]))
        return step(closed.poses) - step(estimate)

    assert grown(5) > 3 * max(grown(i) for i in range(len(lengths)) if i != 5)
    assert step_sigmas(np.linalg.inv(truth[5]) @ truth[6])[3] > step_sigmas(truth[1])[3]


def test_a_walk_follows_the_other_devices_keyframes_it_saw_where_they_moved() -> None:
    """A walk of ten keyframes (ids 0–9, 0.3 m steps) was tracked on another device's
    keyframes: A (tagged id) beside its first keyframe, B beside its last. That device's loop
    moves B 3 cm and leaves A: the walk bends — its first keyframe stays (the map's frame),
    its last moves most of the 3 cm with B, those between in proportion; had its last
    keyframe been posed mostly on its own map's points, it would move much less. Tied to
    nothing, the walk stays (None); tied to A alone, which did not move, it stays too."""
    tag = 1 << 40
    walk = {i: _yaw(0.0, 0.3 * i) for i in range(10)}
    a, b = tag | 0, tag | 9
    before = {a: _yaw(0.0, 0.0, 0.5), b: _yaw(0.0, 2.7, 0.5)}
    moved_b = _yaw(0.0, 2.7 + 0.03, 0.5)
    steps = {(i, i + 1): 150 for i in range(9)}
    posed_on = {0: 200, 9: 200}                 # every point of 0 and 9 an anchor's
    both = follow_anchors(walk, Anchors(before, {a: before[a], b: moved_b},
                                        {(0, a): 200, (9, b): 200}, posed_on), steps)
    assert both is not None
    shift = [both.poses[i][0, 3] - walk[i][0, 3] for i in range(10)]
    assert abs(shift[0]) < 1e-6 and 0.02 < shift[9] <= 0.03, shift
    assert all(x < y for x, y in itertools.pairwise(shift)), shift
    assert follow_anchors(walk, Anchors(before, {a: before[a], b: moved_b}, {}, posed_on),
                          steps) is None
    held = follow_anchors(walk, Anchors(before, {a: before[a]}, {(0, a): 200}, posed_on), steps)
    assert held is not None
    for i in range(10):
        np.testing.assert_allclose(held.corrections[i], np.eye(4), atol=1e-9)
    # a keyframe that observed B's 200 points among 2000 of its own map inherited a tenth of
    # B's error: it moves much less
    mostly_own = follow_anchors(walk, Anchors(before, {b: moved_b}, {(9, b): 200}, {9: 2000}),
                                steps)
    assert mostly_own is not None
    assert 0.0 < mostly_own.poses[9][0, 3] - walk[9][0, 3] < 0.5 * shift[9]
    # a copy whose points it observed fewer of than a tie needs holds nothing
    assert follow_anchors(walk, Anchors(before, {b: moved_b}, {(9, b): ANCHOR_SHARED_MIN - 1},
                                        posed_on), steps) is None


def test_a_loop_bends_the_walk_where_no_other_devices_keyframe_holds_it() -> None:
    """The walk of ten keyframes closes a loop from 9 on 0 measured 3 cm longer than the
    walk has it. Alone, keyframe 9 moves most of the 3 cm. Its last keyframes 7–9 were
    posed on another device's keyframe (an anchor, which the loop does not move): held to
    it, 9 moves less than half as far."""
    tag = 1 << 40
    walk = {i: _yaw(0.0, 0.3 * i) for i in range(10)}
    copy = tag | 8
    anchor = {copy: _yaw(0.0, 2.4, 0.5)}
    steps = {(i, i + 1): 150 for i in range(9)}
    measured = np.linalg.inv(walk[0]) @ _yaw(0.0, 2.73)
    alone = close_loop(walk, 0, 9, measured, steps)
    held = close_loop(walk, 0, 9, measured, steps,
                      anchors=Anchors(anchor, anchor, {(k, copy): 200 for k in (7, 8, 9)},
                                      {k: 200 for k in (7, 8, 9)}))
    moved_alone = alone.poses[9][0, 3] - walk[9][0, 3]
    moved_held = held.poses[9][0, 3] - walk[9][0, 3]
    assert moved_alone > 0.02 and 0.0 <= moved_held < 0.5 * moved_alone
    assert set(held.corrections) == set(walk)           # the anchor is no keyframe of the walk


def test_a_loop_with_another_devices_keyframe_bends_the_walk_towards_it() -> None:
    """The walk of ten keyframes drifted 6 cm along its way from a place another device
    mapped: that device's keyframe beside the walk's last (an anchor, tied to nothing) sees
    keyframe 9 6 cm further on than the walk has it. The loop across devices moves 9 most of
    the 6 cm (four fifths: the walk's nine steps resist, σ 2 cm, the loop's σ 1 cm) towards
    where the other map puts it, the walk's start stays (the map's frame),
    the anchor stays where its own map has it; the loop, kept, holds 9 there in the next
    graph too — a later loop of the walk's own does not undo it — and moves the walk with
    the other device's keyframe when that device's own loop moves it."""
    tag = foreign_tag(MAX_SOURCES - 1)         # a device's tag: beyond a graph key's index
    walk = {i: _yaw(0.0, 0.3 * i) for i in range(10)}
    copy = tag | 9
    anchor = {copy: _yaw(0.0, 2.76, 0.5)}
    steps = {(i, i + 1): 150 for i in range(9)}
    # seen from the other device's keyframe (at (2.76, 0.5)), 9 stands at (2.76, 0); the walk
    # has it at (2.70, 0)
    measured = np.linalg.inv(anchor[copy]) @ _yaw(0.0, 2.76)
    none_tied = Anchors(anchor, anchor, {}, {})
    closed = close_loop(walk, copy, 9, measured, steps, anchors=none_tied)
    assert set(closed.corrections) == set(walk)
    moved = [closed.poses[i][0, 3] - walk[i][0, 3] for i in range(10)]
    assert abs(moved[0]) < 1e-6 and 0.04 < moved[9] <= 0.06, moved
    assert all(x <= y + 1e-9 for x, y in itertools.pairwise(moved)), moved
    # without the anchor the loop has nothing to join
    with pytest.raises(ValueError, match="two keyframes"):
        close_loop(walk, copy, 9, measured, steps)
    # kept as an earlier loop, it holds 9 near the other device's keyframe while a loop of
    # the walk's own (0 on 5, measured as the walk had it before: it pulls the bend back)
    # closes; without it, 9 goes most of the way back
    corrected = closed.poses
    own_loop = np.linalg.inv(walk[0]) @ walk[5]
    kept = close_loop(corrected, 0, 5, own_loop, steps, earlier=[LoopEdge(copy, 9, measured)],
                      anchors=none_tied)
    forgotten = close_loop(corrected, 0, 5, own_loop, steps, anchors=none_tied)
    assert kept.poses[9][0, 3] > corrected[9][0, 3] - 0.005
    assert forgotten.poses[9][0, 3] < corrected[9][0, 3] - 0.01
    # and a loop of that device moving its keyframe moves the walk with it
    followed = follow_anchors(corrected, Anchors(anchor, {copy: _yaw(0.0, 2.79, 0.5)}, {}, {}),
                              steps, [LoopEdge(copy, 9, measured)])
    assert followed is not None and followed.poses[9][0, 3] - corrected[9][0, 3] > 0.02
