"""What the live report counts: failures, relocalisations and recovery times from
the device's per-frame flags; ATE and RPE against ground truth; jumps of any published pose, the
jitter of the published positions and the error of a place revisited."""

from __future__ import annotations

import math

import numpy as np
import pytest

from twinslam.live.tracking_quality import (
    FrameFlags,
    absolute_trajectory_error,
    anchored_to_keyframes,
    cross_device_revisit_error,
    jitter,
    jump_count,
    relative_pose_error,
    revisit_error,
    rigid_part,
    step_excess_mm,
    tracking_events,
)


def test_losses_relocalisations_and_recovery_times_are_counted() -> None:
    # tracked 0-4, lost 5-7, relocalised at 8, tracked, lost 12-13, tracked again (motion
    # model) at 14, lost from 18 to the end; given out of order as summaries may arrive
    flags = [FrameFlags(i / 10, not (5 <= i <= 7 or 12 <= i <= 13 or i >= 18), i == 8)
             for i in range(20)]
    events = tracking_events(reversed(flags))
    assert (events.frames, events.untracked, events.failures) == (20, 7, 3)
    assert events.relocalisations == 1 and events.unrecovered == 1
    assert events.recover_s == pytest.approx([0.3, 0.2])
    assert events.mean_recover_s == pytest.approx(0.25)
    # the loss still open at the end counts until the last frame (1.8 s to 1.9 s)
    assert events.loss_s == pytest.approx([0.3, 0.2, 0.1])
    assert events.longest_loss_s == pytest.approx(0.3)
    assert events.loss_p95_s == pytest.approx(0.29)          # between 0.2 and 0.3
    assert events.failed_share == pytest.approx(7 / 20)
    nothing = tracking_events([])
    assert math.isnan(nothing.mean_recover_s) and math.isnan(nothing.failed_share)
    assert nothing.loss_p95_s == nothing.longest_loss_s == 0.0


def _walk(n: int) -> dict[int, np.ndarray]:
    poses = {}
    for i in range(n):
        p = np.eye(4)
        p[:3, 3] = [0.02 * i, 0.01 * np.sin(i / 5), 0.0]
        poses[i] = p
    return poses


def test_ate_ignores_a_rigid_offset_and_rpe_sees_a_jump() -> None:
    truth = _walk(60)
    moved = {}
    offset = np.eye(4)
    offset[:3, 3] = [1.0, -2.0, 0.5]                   # another origin: aligned away
    for k, p in truth.items():
        moved[k] = offset @ p
    assert absolute_trajectory_error(moved, truth) == pytest.approx(0.0, abs=1e-9)
    assert relative_pose_error(moved, truth, delta=10) == pytest.approx(0.0, abs=1e-9)
    jumped = {k: p.copy() for k, p in truth.items()}
    for k in range(30, 60):                             # a 10 cm jump halfway
        jumped[k][0, 3] += 0.10
    assert 0.02 < absolute_trajectory_error(jumped, truth) < 0.06
    assert relative_pose_error(jumped, truth, delta=10) > 0.02
    assert math.isnan(absolute_trajectory_error({0: np.eye(4)}, truth))
    assert math.isnan(relative_pose_error(truth, truth, delta=100))


def test_a_jump_is_any_pose_whose_error_rises_by_more_than_30_cm_at_once() -> None:
    """Not only relocalisations: a pose that drifts off slowly is no jump, one that leaps is,
    also across untracked frames (the content moves at once when the pose comes back), and a
    pose that comes back from far off is no jump either (the error falls)."""
    errors = {0: 0.01, 1: 0.02, 2: 0.40, 3: 0.05, 4: 0.10, 5: 0.20, 6: 0.30, 7: 0.45,
              20: 1.2e12, 21: 0.02}
    assert jump_count(errors) == 2                     # 0.02 -> 0.40 and 0.45 -> 1.2e12
    assert jump_count({}) == 0


def test_jitter_is_the_second_difference_of_consecutive_positions() -> None:
    """A steady walk has none; one position 1 cm off shakes its three triples by 10, 20 and
    10 mm; a lost frame breaks the triples it is in."""
    frames = list(range(10))
    walk = {i: np.array([0.01 * i, 0.0, 0.0]) for i in frames}
    assert jitter(walk, frames).rms_mm == pytest.approx(0.0, abs=1e-9)
    shaken = dict(walk)
    shaken[5] = walk[5] + [0.0, 0.01, 0.0]
    out = jitter(shaken, frames)
    assert out.triples == 8 and out.over_visible == 0
    assert out.rms_mm == pytest.approx(math.sqrt((10 ** 2 + 20 ** 2 + 10 ** 2) / 8))
    assert out.median_mm == pytest.approx(0.0, abs=1e-9)
    del shaken[4]                  # lost: triples 2-4, 3-5, 4-6 go; 5-7 still shakes 10 mm
    out = jitter(shaken, frames)
    assert out.triples == 5 and out.rms_mm == pytest.approx(math.sqrt(10 ** 2 / 5))
    assert math.isnan(jitter({}, frames).rms_mm)


def _pose(x: float, y: float = 0.0, yaw_deg: float = 0.0) -> np.ndarray:
    pose = np.eye(4)
    c, s = math.cos(math.radians(yaw_deg)), math.sin(math.radians(yaw_deg))
    pose[:2, :2] = [[c, -s], [s, c]]
    pose[:2, 3] = x, y
    return pose


def test_a_revisit_error_is_the_drift_between_two_visits_of_one_place() -> None:
    """A camera standing at one place for 30 s (a frame a second) looks at it again and
    again. A device that drifts 1 cm a second sideways misplaces an anchor from a visit t
    seconds earlier by 1 cm · t; the same device moved as a whole (any map frame) does not;
    frames under 10 s apart are no revisit."""
    stamps = [int(i * 1e9) for i in range(30)]
    truth = {s: _pose(0.0) for s in stamps}
    drift = {s: _pose(0.0, 0.01 * i) for i, s in enumerate(stamps)}
    error = revisit_error(drift, truth, stamps)
    gaps = np.array([j - i for i in range(30) for j in range(i + 10, 30)], dtype=float)
    assert error.pairs == gaps.size == 210
    assert error.rms_m == pytest.approx(0.01 * math.sqrt(np.mean(gaps ** 2)))
    assert error.median_m == pytest.approx(0.01 * np.median(gaps))
    moved = {s: _pose(5.0, -2.0, 30.0) @ p for s, p in truth.items()}
    assert revisit_error(moved, truth, stamps).rms_m == pytest.approx(0.0, abs=1e-12)
    assert revisit_error(drift, truth, stamps, gap_s=31.0).pairs == 0


def test_content_anchored_to_keyframes_follows_a_loops_correction() -> None:
    """A walk out along x and back, the way out published 5 cm off in y (drift) until a loop
    corrects its keyframes; the way back is tracked on the corrected map. In map coordinates
    the first visit stays 5 cm off and the revisit error counts the correction; anchored to
    the keyframes the first visit moves with them and the revisit agrees with the truth. A
    keyframe that never moved anchors nothing away; a frame before every keyframe anchors to
    the oldest."""
    stamps = [int(i * 1e9) for i in range(40)]
    truth = {i: _pose(0.1 * (i if i < 20 else 39 - i)) for i in range(40)}
    drift = _pose(0.0, 0.05)
    published = {i: drift @ truth[i] if i < 20 else truth[i] for i in range(40)}
    out_keyframes = {k: drift @ truth[k] for k in (2, 10)}          # as published going out
    then = {i: (out_keyframes if i < 20 else {2: truth[2], 10: truth[10]}) for i in range(40)}
    now = {2: truth[2], 10: truth[10]}                               # after the loop
    anchored = anchored_to_keyframes(published, then, now)
    as_stamps = {stamps[i]: p for i, p in published.items()}
    truth_stamps = {stamps[i]: p for i, p in truth.items()}
    assert revisit_error(as_stamps, truth_stamps, stamps).rms_m == pytest.approx(0.05)
    anchored_stamps = {stamps[i]: p for i, p in anchored.items()}
    assert revisit_error(anchored_stamps, truth_stamps, stamps).rms_m == \
        pytest.approx(0.0, abs=1e-12)
    assert np.allclose(anchored[0], truth[0]) and np.allclose(anchored[15], truth[15])
    unmoved = anchored_to_keyframes(published, then, {k: then[0][k] for k in (2, 10)})
    assert all(np.allclose(unmoved[i], published[i]) for i in range(20))
    assert np.allclose(anchored_to_keyframes({0: published[0]}, {}, now)[0], published[0])


def test_a_cross_device_revisit_error_is_where_one_device_sees_the_others_content() -> None:
    """Two devices in one place, each frame paired with the other device's frames within
    0.3 m and 20° (never with its own): where the second device's map has the place 2 cm
    off the first's, every pair is 2 cm off; both maps moved together (one shared frame,
    anywhere) changes nothing; the second device in a frame of its own — 1 m away — is off
    by as much; frames 1 m apart or turned 90° are no pair."""
    first_truth = [_pose(0.05 * i) for i in range(5)]                  # x 0 .. 0.2
    second_truth = [_pose(0.05 * i, 0.0, 10.0) for i in range(5)] + \
        [_pose(1.0), _pose(0.0, 0.0, 90.0)]                         # no pair for the last two
    first = [(t, t) for t in first_truth]
    off = _pose(0.0, 0.02)
    second = [(off @ t, t) for t in second_truth]
    error = cross_device_revisit_error(first, second)
    assert error.pairs == 25 and error.rms_m == pytest.approx(0.02)
    anywhere = _pose(3.0, -1.0, 40.0)
    moved = cross_device_revisit_error([(anywhere @ e, t) for e, t in first],
                                       [(anywhere @ e, t) for e, t in second])
    assert moved.pairs == 25 and moved.rms_m == pytest.approx(0.02)
    apart = cross_device_revisit_error(first, [(_pose(1.0) @ t, t) for t in second_truth])
    assert apart.rms_m == pytest.approx(1.0)
    alone = cross_device_revisit_error(first, [])
    assert alone.pairs == 0 and math.isnan(alone.rms_m)


def test_one_rigid_motion_takes_out_a_misplaced_map_and_leaves_a_bent_one() -> None:
    """The cross-device error split in two. The second device's map placed 3 cm and 2° off
    the first's (a merge's alignment that missed): one rigid motion takes it all out, and
    that motion puts every one of its frames back where the truth has it. Its map bent
    instead (an offset growing along the walk, as two walks drift apart): a rigid motion
    takes out part, never more than there is, and what is left is the bend. Two devices
    with no pair: nothing to split."""
    grid = [(0.05 * i, 0.04 * j) for i in range(6) for j in range(3)]       # not one line
    first_truth = [_pose(x, y) for x, y in grid]
    second_truth = [_pose(x + 0.01, y, 5.0) for x, y in grid]
    first = [(t, t) for t in first_truth]
    off = _pose(0.03, -0.01, 2.0)
    misplaced = [(off @ t, t) for t in second_truth]
    error = cross_device_revisit_error(first, misplaced)
    split = rigid_part(first, misplaced)
    assert error.rms_m > 0.02
    assert split.left.pairs == error.pairs and split.left.rms_m < 1e-9
    assert all(np.allclose((split.motion @ e)[:3, 3], t[:3, 3], atol=1e-9)
               for e, t in misplaced)
    assert split.turned_deg == pytest.approx(2.0, abs=1e-6) and 0.0 < split.moved_m < 0.1
    bent = [(_pose(t[0, 3], t[1, 3] + 0.2 * t[0, 3] ** 2 * 10, 5.0), t) for t in second_truth]
    bent_error = cross_device_revisit_error(first, bent)
    bent_split = rigid_part(first, bent)
    assert 0.003 < bent_split.left.rms_m < bent_error.rms_m
    nobody = rigid_part(first, [])
    assert nobody.left.pairs == 0 and np.array_equal(nobody.motion, np.eye(4))


def test_a_place_seen_from_elsewhere_or_turned_away_from_is_no_revisit() -> None:
    """Only pairs within 0.3 m and 20° of each other count; untracked frames (not in
    ``stamps``) and frames without a pose are left out."""
    stamps = [int(i * 1e9) for i in range(40)]
    # 0-9 at the origin, 10-19 a metre away, 20-29 back at the origin turned by 90°,
    # 30-39 at the origin turned by 15°
    truth = {s: _pose(1.0 if 10 <= i < 20 else 0.0, 0.0,
                      90.0 if 20 <= i < 30 else 15.0 if i >= 30 else 0.0)
             for i, s in enumerate(stamps)}
    est = dict(truth)
    # frames 0-9 pair with 30-39 (15°, ≥ 21 s apart): 100 pairs; 10-19 with nothing
    assert revisit_error(est, truth, stamps).pairs == 100
    assert revisit_error(est, truth, stamps[5:]).pairs == 50          # 0-4 untracked
    del est[stamps[35]]
    assert revisit_error(est, truth, stamps).pairs == 90
    empty = revisit_error({}, truth, stamps)
    assert empty.pairs == 0 and math.isnan(empty.rms_m)


def test_a_step_beyond_the_truths_is_what_content_anchored_there_leaps() -> None:
    """A camera walking 1 cm a frame: a track that steps 1 cm too goes no further than it,
    one that leaps 3 cm once goes 2 cm beyond; frames without a position are left out."""
    frames = list(range(10))
    truth = {i: np.array([0.01 * i, 0.0, 0.0]) for i in frames}
    assert step_excess_mm(truth, truth, frames) == pytest.approx(0.0)
    leap = {i: p + (np.array([0.02, 0, 0]) if i >= 5 else 0.0) for i, p in truth.items()}
    assert step_excess_mm(leap, truth, frames) == pytest.approx(20.0)
    assert math.isnan(step_excess_mm({}, truth, frames))
