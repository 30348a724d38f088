"""What the live report counts: failures, relocalisations and recovery times from
the device's per-frame flags; ATE and RPE against ground truth."""

from __future__ import annotations

import math

import numpy as np
import pytest

from twinslam.live.tracking_quality import (
    FrameFlags,
    absolute_trajectory_error,
    relative_pose_error,
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
