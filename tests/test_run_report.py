"""A live run's report from what the monitor heard: a pose that leaps counts as a jump whatever
its cause, the largest error, the jitter of the published positions beside the truth's, the
poses and keyframes the gates refused, the longest stretch of slots without an upload, and the
error of a place revisited."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from device_tracker.messages import FrameRecord, frame_summaries_message, uplink_throughput_message
from edge_mapper.messages import map_stats_message
from msg_schemas.headers import time_key
from twinslam.live.report import in_final_frame, print_table, report
from twinslam.live.run_log import RunLog
from twinslam.slam.back_end.keyframe_map import KeyFrameMap
from twinslam.slam.map_update import MapSnapshot
from twinslam.uplink.shaper import SlotThroughput

SLOT = 10


def _truth(i: int) -> np.ndarray:
    """Frame ``i`` of a walk curving off x: 1 cm a frame along x, 0.5 mm·i² along y (its
    second difference: 1 mm a frame)."""
    pose = np.eye(4)
    pose[:2, 3] = 0.01 * i, 0.0005 * i * i
    return pose


def _off(pose: np.ndarray, dx: float) -> np.ndarray:
    moved = pose.copy()
    moved[0, 3] += dx
    return moved


def _run() -> RunLog:
    """Four slots of 10 frames of :func:`_truth`'s walk. The device's estimate shakes by
    ±2 mm, leaps 0.5 m off at frame 25 (tracked: a wrong solve no relocalisation made) and
    is back at 26; frames 30-31 are lost, 31 with a refused pose. Keyframes go up in slots
    0 and 3 only; the edge refused one keyframe of slot 3; its map was in pieces at slots 0
    and 2."""
    log = RunLog()
    for slot in range(4):
        frames = []
        for i in range(slot * SLOT, (slot + 1) * SLOT):
            estimate = _off(_truth(i), 0.002 if i % 2 else -0.002)
            if i == 25:
                estimate = _off(_truth(i), 0.5)
            tracked = i not in (30, 31)
            frames.append(FrameRecord(i, i / 30.0, estimate, tracked, np.zeros(0, np.uint64),
                                      np.zeros(0, np.uint64), slot, pose_refused=i == 31,
                                      pnp_ransac=i in (5, 6, 31)))
        msg = frame_summaries_message(slot, 40.0, 0, slot, frames, frames[-1].stamp)
        log.summaries[slot] = msg
        for f, record in zip(msg.frames, frames, strict=True):
            log.poses[time_key(f.stamp)] = record.pose
            log.ground_truth[time_key(f.stamp)] = _truth(record.frame_id)
        sent = 2 if slot in (0, 3) else 0
        log.throughput[slot] = uplink_throughput_message(
            SlotThroughput(slot, 40.0, 0, sent * 625_000, 0.5, sent), slot + 0.5)
        # the edge's map in pieces at slots 0 and 2 (u(G) = +inf)
        pieces = math.inf if slot in (0, 2) else 0.0
        log.stats[slot] = map_stats_message(slot, "lff", KeyFrameMap(), pieces, None, sent, 0.0,
                                            1.0, slot + 0.6, refused=int(slot == 3),
                                            missing=int(slot == 1))
    return log


def test_the_report_counts_a_leap_jitter_refusals_and_slots_without_upload() -> None:
    rep = report("lff", _run(), 2.0, SLOT)
    assert rep.jumps == 1                                    # the leap at 25; 26 falls back
    assert rep.max_error_m == pytest.approx(0.5, abs=0.02)
    # the ±2 mm shake alone is 8 mm a triple; the leap's triples shake by 0.5 and 1 m
    assert rep.jitter_median_mm == pytest.approx(8.0, abs=0.5)
    assert rep.jitter_over_20mm == 3 and rep.jitter_p95_mm > 100
    assert rep.truth_jitter_rms_mm == pytest.approx(1.0)   # the walk's own curve
    assert rep.poses_refused == 1 and rep.keyframes_refused == 1 and rep.keyframes_missing == 1
    # frames 5 and 6 of the 38 tracked were posed by PnP RANSAC (31, untracked, counts not)
    assert rep.pnp_ransac_share == pytest.approx(2 / 38)
    assert rep.longest_no_upload_slots == 2                   # slots 1 and 2
    # a map in pieces at slot 2 is counted; slot 0's is not (it plans on an empty map, as
    # the lost share leaves it out), and the table shows the count beside the loops
    assert rep.map_in_pieces_slots == 1
    assert "loops pieces" in rep.HEADER
    # and says under the table what that did to the lost share
    lines: list[str] = []
    print_table([rep], lines.append)
    assert lines[-1] == ("lff: the edge's map was in pieces (u(G) = +inf) in 1 of its 3 slots "
                         "after the first; every frame of those slots counts as lost whatever "
                         "the device tracked (lost 0.0%, 2 frames untracked)")
    assert dataclasses.replace(rep, map_in_pieces_slots=0.0).pieces_line("lff") is None
    # no device/odom heard: nothing to say of the odom frame
    assert math.isnan(rep.odom_jitter_rms_mm) and math.isnan(rep.odom_step_excess_mm)
    # 1.3 s of a walk that never comes back: no place is revisited, nothing to measure
    assert rep.revisit_pairs == 0 and math.isnan(rep.revisit_error_m)
    assert "revis m" in rep.HEADER
    # launch's table shows it, in the column before the dropped (and skipped) frames; a
    # player that said nothing of its skips leaves that cell unknown
    assert rep.HEADER.endswith("no up dropped skipped")
    assert rep.row().split()[-3:] == ["2", "0", "nan"]


def _short_of(log: RunLog, slot: int, frames: int) -> None:
    """``log``'s ``slot`` with its last ``frames`` frames gone (never reached the device)."""
    del log.summaries[slot].frames[-frames:]


def _keyframes(version: int, poses: dict[int, np.ndarray]) -> MapSnapshot:
    """A map update of keyframes ``poses`` (id → camera-to-map) and no points."""
    return MapSnapshot(version, np.array(list(poses), dtype=np.uint64),
                       np.array(list(poses.values())), np.zeros(0, np.uint64),
                       np.zeros((0, 3)), np.zeros((0, 32), np.uint8), np.zeros(0, np.uint32))


#: the walk's sideways drift on the way out, which the loop takes out
DRIFT = np.eye(4)
DRIFT[1, 3] = 0.05


def _walk_out_and_back(corrected_in_map: bool) -> tuple[RunLog, dict[int, np.ndarray]]:
    """A 40 s walk out along a curve and back, a frame a second. Going out the device tracks
    on map version 1, whose keyframes (0 and 10) drifted 5 cm sideways with it; a loop then
    moves them back, and the way back is tracked on version 2. ``corrected_in_map``: version
    2 carries keyframes 0 and 10 corrected; else they left the map before the loop (version
    2 holds keyframe 30 only) and no map update carries their correction. Returns the log
    and the truth by frame id."""
    truth = {i: np.eye(4) for i in range(40)}
    for i, pose in truth.items():
        along = i if i < 20 else 39 - i
        pose[:2, 3] = 0.1 * along, 0.001 * along * along     # a curve: ATE can align it
    log = RunLog()
    for slot in range(2):
        frames = [FrameRecord(i, float(i), DRIFT @ truth[i] if slot == 0 else truth[i], True,
                              np.zeros(0, np.uint64), np.zeros(0, np.uint64), slot,
                              map_version=slot + 1)
                  for i in range(slot * 20, (slot + 1) * 20)]
        msg = frame_summaries_message(slot, 40.0, 0, slot + 1, frames, frames[-1].stamp)
        log.summaries[slot] = msg
        for f, record in zip(msg.frames, frames, strict=True):
            log.poses[time_key(f.stamp)] = record.pose
            log.ground_truth[time_key(f.stamp)] = truth[record.frame_id]
        log.map_stamps[slot] = int(20e9) * (slot + 1)
    log.maps[0] = _keyframes(1, {k: DRIFT @ truth[k] for k in (0, 10)})
    log.maps[1] = _keyframes(2, {k: truth[k] for k in (0, 10)} if corrected_in_map
                             else {30: truth[30]})
    return log, truth


def test_a_loop_s_correction_is_no_revisit_error_of_content_anchored_to_keyframes() -> None:
    """In map coordinates every revisit of the walk is 5 cm off; anchored to the keyframes
    the first visit moves with them, as the map updates moved them; without the loop it
    keeps the drift."""
    log, truth = _walk_out_and_back(corrected_in_map=True)
    rep = report("lff", log, 40.0, 20)
    assert rep.revisit_error_m == pytest.approx(0.05)
    assert rep.anchored_revisit_error_m == pytest.approx(0.0, abs=1e-9)
    log.maps[1] = _keyframes(2, {k: DRIFT @ truth[k] for k in (0, 10)})    # no loop
    assert report("lff", log, 40.0, 20).anchored_revisit_error_m == pytest.approx(0.05)


def test_content_anchored_to_an_archived_keyframe_moves_where_the_edge_s_trajectory_puts_it(
        ) -> None:
    """The first visit's keyframes left the map before the loop corrected them: no map update
    carries the correction, and anchored to what the device heard the revisit stays 5 cm off.
    The edge's keyframe trajectory (every keyframe kept, by capture stamp) does carry it, and
    anchored to it the revisit error is gone, and so is the ATE of the walk as the final map
    has it (ORB-SLAM's saved trajectory); a map update stamped after the trajectory
    supersedes it for the keyframes it carries."""
    log, truth = _walk_out_and_back(corrected_in_map=False)
    assert report("lff", log, 40.0, 20).anchored_revisit_error_m == pytest.approx(0.05)
    stamps = {int(f.frame_id): time_key(f.stamp) for s in log.summaries.values()
              for f in s.frames}
    log.keyframe_trajectory = {stamps[k]: truth[k] for k in (0, 10, 30)}
    log.trajectory_stamp = log.map_stamps[1]       # sent with the slot's map update
    rep = report("lff", log, 40.0, 20)
    assert rep.anchored_revisit_error_m == pytest.approx(0.0, abs=1e-9)
    # the whole walk as the final map has it is the truth; as published, half of it drifted
    assert rep.anchored_ate_m == pytest.approx(0.0, abs=1e-6) and rep.ate_m > 0.01
    # a later map update puts keyframes 0 and 10 back where they drifted to
    log.maps[2] = _keyframes(3, {k: DRIFT @ truth[k] for k in (0, 10)})
    log.map_stamps[2] = log.trajectory_stamp + 1
    assert report("lff", log, 40.0, 20).anchored_revisit_error_m == pytest.approx(0.05)


def test_frames_the_player_skipped_are_not_counted_as_dropped() -> None:
    """Three frames of slot 1 never reached the device. The player skipped one of them (an
    unreadable file, as it says on /diagnostics): two were dropped — the machine's fault —
    and one skipped — the data's; without the player's word all three count as dropped."""
    log = _run()
    _short_of(log, 1, 3)
    assert report("lff", log, 2.0, SLOT).frames_dropped == 3
    log.frames_skipped = 1
    rep = report("lff", log, 2.0, SLOT)
    assert (rep.frames_dropped, rep.frames_skipped) == (2, 1)
    assert rep.row().split()[-2:] == ["2!", "1"]
    # a run of an unreadable sequence, not a slow machine: nothing left to call dropped
    log.frames_skipped = 5
    assert report("lff", log, 2.0, SLOT).frames_dropped == 0


def test_a_frame_dropped_in_the_last_slot_is_counted_up_to_its_newest_summarised_frame(
        ) -> None:
    """The run may end inside its last slot, so a slot's length cannot say what it lost; the
    player's ground truth (a pose a frame it published) can, up to the newest frame the device
    summarised: frames 33 and 34 of slot 3 published and never summarised are dropped, the
    slot's last three (the run ended) are not."""
    log = _run()
    assert report("lff", log, 2.0, SLOT).frames_dropped == 0
    last = log.summaries[3].frames
    del last[3:5]                                        # frames 33 and 34
    assert report("lff", log, 2.0, SLOT).frames_dropped == 2
    del last[-3:]                                        # 37-39: after the newest summarised
    assert report("lff", log, 2.0, SLOT).frames_dropped == 2
    log.ground_truth = {}                                # no ground truth: no way to tell
    assert report("lff", log, 2.0, SLOT).frames_dropped == 0


def test_the_odom_frame_is_judged_by_its_jitter_and_its_largest_leap() -> None:
    """The same run with device/odom heard: an odom pose that follows the walk without the
    map pose's leap at frame 25 shakes like the truth and never steps further than the
    camera moved; one that leaps 5 cm at frame 12 shows the 5 cm."""
    log = _run()
    for summary in log.summaries.values():
        for f in summary.frames:
            log.odom_poses[time_key(f.stamp)] = _truth(int(f.frame_id))
    rep = report("lff", log, 2.0, SLOT)
    assert rep.odom_jitter_rms_mm == pytest.approx(1.0)          # the walk's own curve
    assert rep.odom_step_excess_mm == pytest.approx(0.0, abs=1e-9)
    key = time_key(log.summaries[1].frames[2].stamp)                  # frame 12
    log.odom_poses[key] = _off(log.odom_poses[key], 0.05)
    leapt = log.odom_poses[key][:3, 3] - _truth(11)[:3, 3]
    walked = _truth(12)[:3, 3] - _truth(11)[:3, 3]
    expected = (np.linalg.norm(leapt) - np.linalg.norm(walked)) * 1000.0     # ~46 mm
    assert report("lff", log, 2.0, SLOT).odom_step_excess_mm == pytest.approx(expected)


def test_a_merged_devices_poses_are_judged_in_the_frame_it_ended_in() -> None:
    """A device whose map the edge merged into another device's frame at map version 2: its
    poses before (tracked on version 1, its own frame 2 m and 30° away) and after (in the
    other device's frame) are one walk once the merge's motion carries the first ones over —
    no 2 m leap, no error; the published poses themselves stay as they were."""
    moved = np.eye(4)
    a = math.radians(30.0)
    moved[:2, :2] = [[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]]
    moved[:3, 3] = [2.0, -1.0, 0.5]
    log = _run()
    own = {}
    for slot, msg in log.summaries.items():
        version = 1 if slot < 2 else 2
        for f in msg.frames:
            f.map_version = version
            f.tracked = True
            key = time_key(f.stamp)
            truth = log.ground_truth[key]
            log.poses[key] = np.linalg.inv(moved) @ truth if version == 1 else truth
            own[key] = log.poses[key]
    empty = _keyframes(0, {})
    log.maps = {0: dataclasses.replace(empty, version=1, frame_id="ar2/map"),
                2: dataclasses.replace(empty, version=2, frame_id="ar1/map",
                                       frame_correction=moved)}
    carried = in_final_frame(log)
    assert all(np.allclose(carried[k], log.ground_truth[k]) for k in carried)
    rep = report("lff", log, 2.0, SLOT)
    assert rep.ate_m < 1e-9 and rep.jumps == 0 and rep.max_error_m < 1e-9
    assert all(log.poses[k] is own[k] for k in own)          # the record is untouched
    # a map that never changed frame: its poses as published
    log.maps = {0: dataclasses.replace(empty, version=1, frame_id="ar2/map")}
    assert in_final_frame(log) is log.poses
