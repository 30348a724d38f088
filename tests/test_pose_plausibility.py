"""No pose a camera could not have reached passes: faults injected into the device's pose solver,
into the edge's uploads and into a relocalisation answer are refused, counted and recovered
from — the device never publishes them as tracked, the edge never lets them into its map or
archive."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from device_tracker.device_core import DeviceTrackerCore
from device_tracker.frame_log import frame_log_lines
from edge_mapper.edge_core import EdgeConfig, EdgeMapperCore, SlotOutcome
from edge_mapper.slot_planner import SlotConfig
from tests.test_edge_core import Device, F, K
from twinslam.policies.registry import make_policy
from twinslam.sequences.synthetic import SyntheticSequence
from twinslam.slam.back_end.map_back_end import BackEndConfig
from twinslam.slam.map_update import MapSnapshot
from twinslam.slam.pose_plausibility import MotionBounds, implausible_speed, implausible_step


def _moved(x: float = 0.0, turn_deg: float = 0.0) -> np.ndarray:
    pose = np.eye(4)
    c, s = np.cos(np.radians(turn_deg)), np.sin(np.radians(turn_deg))
    pose[:3, :3] = [[c, 0, s], [0, 1, 0], [-s, 0, c]]
    pose[0, 3] = x
    return pose


def test_the_motion_bounds_refuse_what_no_camera_can_do_and_pass_what_a_user_does() -> None:
    bounds = MotionBounds()
    still = np.eye(4)
    assert implausible_step(still, _moved(0.05, 3.0), 1, bounds) == ""    # a brisk step
    assert "moved 0.50 m in 1 frame" in implausible_step(still, _moved(0.5), 1, bounds)
    assert implausible_step(still, _moved(0.5), 3, bounds) == ""          # 3 frames lost between
    assert "turned 45°" in implausible_step(still, _moved(0.0, 45.0), 1, bounds)
    # a map update's correction is no motion: 0.4 m at a swap passes, 0.6 m does not
    assert implausible_step(still, _moved(0.4), 1, bounds, map_changed=True) == ""
    assert implausible_step(still, _moved(0.6), 1, bounds, map_changed=True) != ""
    nan = _moved(0.0)
    nan[1, 3] = np.nan
    assert implausible_step(still, nan, 1, bounds) == "a non-finite pose"
    # steps each under the bound that add up to a speed no user reaches (15 × 0.15 m in 0.5 s)
    assert "faster than 3.0 m/s" in implausible_speed(still, _moved(2.25), 15, 30.0, bounds)
    assert implausible_speed(still, _moved(1.0), 15, 30.0, bounds) == ""
    with pytest.raises(ValueError, match="max_step_m"):
        MotionBounds(max_step_m=0.0)


def _track(core: DeviceTrackerCore, frames: list) -> list:
    return [core.track(f.color, f.depth, f.stamp) for f in frames]


def _error(record, truth_first: np.ndarray, truth: np.ndarray) -> float:
    rel = np.linalg.inv(truth_first) @ truth
    return float(np.linalg.norm(record.pose[:3, 3] - rel[:3, 3]))


def test_a_diverging_pose_solver_is_caught_and_the_device_recovers_by_relocalisation(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """The motion model's solve drifts off exponentially (2 cm, 4 cm, ... doubling a frame) for
    ten frames, as a solve against a degenerate map does. The device never counts a pose more
    than half a metre off as tracked: the motion gate refuses the first impossible step, the
    frame is lost and flagged, the log says why, and once the fault is gone the device is
    tracked again by relocalisation, on the truth."""
    seq = SyntheticSequence(45, seed=0)
    frames = list(seq)
    core = DeviceTrackerCore(seq.intrinsics, 60)
    solve = core.tracking._solve_pose

    def diverging(pixels: np.ndarray, ids: np.ndarray, predicted: np.ndarray | None,
                  depth: np.ndarray | None = None):
        pose, mask = solve(pixels, ids, predicted, depth)
        k = core.tracking.frames_tracked - 1 - 10          # the frame being tracked, from 10
        if pose is not None and predicted is not None and 0 <= k < 10:
            pose = pose.copy()
            pose[:3, 3] += [0.02 * 2 ** k, 0.0, 0.0]
        return pose, mask

    monkeypatch.setattr(core.tracking, "_solve_pose", diverging)
    results = _track(core, frames)
    first = frames[0].pose
    refused = [r for r in results if r.implausible]
    assert refused, "the diverging solve was never refused"
    assert all(r.record.pose_refused and not r.record.tracked for r in refused)
    # by frame 16 the doubling step (1.28 m) is no camera's; a step under the bound (0.16 m
    # at frame 14) passes, which is why the bounds are a human's and not tighter
    assert "moved" in refused[0].implausible and refused[0].record.frame_id <= 16
    tracked_errors = [_error(r.record, first, f.pose) for r, f in zip(results, frames,
                                                                         strict=True)
                      if r.record.tracked]
    assert max(tracked_errors) < 0.5
    lines = frame_log_lines(refused[0])
    assert lines[0].warning and "pose refused" in lines[0].text
    # the fault ended at frame 20: tracked again, on the truth, well before the end
    back = [r for r in results[20:] if r.record.tracked]
    assert back and back[0].record.frame_id < 35
    assert all(_error(r.record, first, frames[r.record.frame_id].pose) < 0.05 for r in back)


def test_a_relocalisation_answer_metres_off_is_refused() -> None:
    """The edge answers a lost device with a map update that brings the place back — but the
    map it sends sits 3 m from where the device was (a wrong place recognised, a map gone
    astray). Every point matches and RANSAC finds a pose on it; the pose gate refuses it, so
    the device stays lost instead of publishing a pose 3 m off."""
    seq = SyntheticSequence(14, seed=0)
    frames = list(seq)
    core = DeviceTrackerCore(seq.intrinsics, 60)
    _track(core, frames[:10])
    held = core.tracking.map
    ids = np.arange(1, len(held) + 1, dtype=np.uint64)
    shifted = MapSnapshot(1, np.zeros(0, np.uint64), np.zeros((0, 4, 4)), ids,
                          held.positions + np.array([3.0, 0.0, 0.0]), held.descriptors.copy(),
                          np.ones(len(ids), np.uint32), [], np.zeros(0, np.uint64),
                          np.zeros(0, np.uint64))
    assert core.apply_map_update(shifted, 0)
    answered = _track(core, frames[10:14])
    assert not any(r.record.tracked for r in answered)
    assert "m from the last tracked pose" in answered[0].refused
    assert all(r.record.pose_refused for r in answered if r.refused)
    assert all(np.linalg.norm(r.record.pose[:3, 3]) < 1.0 for r in answered)


def _edge(vmax: int = 10) -> tuple[EdgeMapperCore, Device]:
    device = Device(np.random.default_rng(3))
    core = EdgeMapperCore(make_policy("lff"), K, EdgeConfig(slot=SlotConfig(vmax=vmax),
                                                            back_end=BackEndConfig(ba_window=5)))
    for slot in range(3):
        frames = [device.summary(f, core) for f in range(slot * F, (slot + 1) * F)]
        plan = core.plan(slot, frames, 80.0, 1)
        for f in plan.action.upload:
            assert not core.add_keyframe(device.keyframe(f, slot, core)).refused
        core.finish_slot(slot)
    return core, device


@pytest.mark.parametrize("fault", ["far", "nan", "inconsistent"])
def test_the_edge_refuses_a_keyframe_no_camera_could_have_taken(fault: str) -> None:
    """A keyframe at 10¹² m, one with a NaN in its pose, one shifted 0.25 m (within reach)
    so its own matched points reproject tens of pixels off: each is refused, counted with
    its reason, never enters the map or the archive, and counts as an upload that never came
    (the slot evicts only for what it integrated). The slot's other uploads integrate but one
    that never comes: refused and never-come are told apart (MapStats counts each)."""
    core, device = _edge()
    slot = 3
    frames = [device.summary(f, core) for f in range(slot * F, (slot + 1) * F)]
    plan = core.plan(slot, frames, 80.0, 1)
    bad, *good = plan.action.upload
    keyframe = device.keyframe(bad, slot, core)
    pose = keyframe.pose.copy()
    if fault == "far":
        pose[:3, 3] = [2e12, 0.0, 0.0]
    elif fault == "nan":
        pose[1, 3] = np.nan
    else:
        pose[:3, 3] += [0.25, 0.0, 0.0]
    report = core.add_keyframe(dataclasses.replace(keyframe, pose=pose))
    assert report is not None and report.refused
    expected = {"far": "out of reach", "nan": "non-finite",
                "inconsistent": "matched map points reproject"}[fault]
    assert expected in report.refused
    *good, never = good
    for f in good:
        assert not core.add_keyframe(device.keyframe(f, slot, core)).refused
    out = core.finish_slot(slot)
    assert out.refused == {bad: report.refused}
    assert sorted(out.missing) == sorted([bad, never]) and out.not_in == [never]
    assert bad in out.missing and bad not in out.integrated and bad not in core.map.keyframes
    assert bad not in core.archive
    assert len(out.evicted) == len(out.integrated)           # room made only for what came
    assert all(np.isfinite(kf.pose).all() and np.linalg.norm(kf.pose[:3, 3]) < 100
               for kf in core.map.keyframes.values())
    assert all(np.linalg.norm(pt.position) < 100 for pt in core.map.points.values())


def test_a_keyframe_of_a_user_walking_on_passes_the_gate() -> None:
    """The gate's reach follows the time between keyframes: the keyframes of a device walking
    at 1.2 m/s integrate, the next slot's as well as those after three slots that uploaded
    nothing (a metre further on)."""
    core, device = _edge()
    for slot in (3, 4, 5):                                  # planned, nothing uploaded
        core.plan(slot, [device.summary(f, core) for f in range(slot * F, (slot + 1) * F)],
                  80.0, 1)
        core.finish_slot(slot)
    slot = 6
    plan = core.plan(slot, [device.summary(f, core) for f in range(slot * F, (slot + 1) * F)],
                     80.0, 1)
    reports = [core.add_keyframe(device.keyframe(f, slot, core)) for f in plan.action.upload]
    assert reports and all(r is not None and not r.refused for r in reports)
    out = core.finish_slot(slot)
    assert not out.refused and out.integrated == sorted(plan.action.upload)


def _finish_a_slot(core: EdgeMapperCore, device: Device, slot: int = 3
                   ) -> tuple[SlotOutcome, int, dict[int, np.ndarray]]:
    """One slot of the walk through the edge: (its outcome, the newest keyframe it asked for,
    the map's keyframe poses before its end)."""
    frames = [device.summary(f, core) for f in range(slot * F, (slot + 1) * F)]
    plan = core.plan(slot, frames, 80.0, 1)
    for f in plan.action.upload:
        core.add_keyframe(device.keyframe(f, slot, core))
    before = {k: kf.pose.copy() for k, kf in core.map.keyframes.items()}
    return core.finish_slot(slot), max(plan.action.upload), before


def test_a_bundle_adjustment_that_diverged_is_not_applied(monkeypatch: pytest.MonkeyPatch
                                                          ) -> None:
    """The optimiser answers with the newest keyframe moved 5 m: the edge keeps the map as it
    was and says why in the slot's outcome."""
    import twinslam.slam.back_end.map_back_end as back_end

    core, device = _edge()
    solve = back_end.bundle_adjust

    def diverged(*args: object, **kwargs: object):
        result = solve(*args, **kwargs)            # type: ignore[arg-type]
        newest = max(result.poses)
        result.poses[newest] = result.poses[newest].copy()
        result.poses[newest][0, 3] += 5.0
        return result

    monkeypatch.setattr(back_end, "bundle_adjust", diverged)
    out, newest, before = _finish_a_slot(core, device)
    assert out.optimisation_refused.startswith(f"keyframe {newest} moved 4.9")
    assert out.bundle_adjustment is not None and out.bundle_adjustment.refused
    for k, kf in core.map.keyframes.items():
        if k in before:
            np.testing.assert_array_equal(kf.pose, before[k])


def test_a_bundle_adjustment_that_raised_its_error_is_not_applied(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """Gauss–Newton takes its steps whatever they do to the error: an answer whose error is
    larger than where it started (here the newest keyframe turned 115° in place, within the
    distance bound) is refused, and the keyframes stay where the device posed them."""
    import twinslam.slam.back_end.map_back_end as back_end

    core, device = _edge()
    solve = back_end.bundle_adjust

    def overshot(*args: object, **kwargs: object):
        result = solve(*args, **kwargs)            # type: ignore[arg-type]
        newest = max(result.poses)
        turn = np.eye(4)
        a = np.radians(115.0)
        turn[:2, :2] = [[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]]
        result.poses[newest] = result.poses[newest] @ turn
        result.final_error = 1000.0 * result.initial_error + 1.0
        return result

    monkeypatch.setattr(back_end, "bundle_adjust", overshot)
    out, _, before = _finish_a_slot(core, device)
    assert out.optimisation_refused.startswith("the adjustment raised its error")
    for k, kf in core.map.keyframes.items():
        if k in before:
            np.testing.assert_array_equal(kf.pose, before[k])
