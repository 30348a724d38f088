"""The edge closes a loop: on a walk out and back whose keyframes drift on the way back, a
keyframe that sees a place the archive holds from the way out is found by place recognition,
confirmed by PnP, and the pose graph puts the drift where the walk had nothing to hold on to
(a step between keyframes that share no point), not over the well-tracked keyframes around it;
the corrected map and archive survive a restart; the worker thread answers as the caller would."""

from __future__ import annotations

import dataclasses
import operator
import os
import sys
import threading
import time
from concurrent.futures import Future
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from edge_mapper.edge_core import EdgeConfig, EdgeMapperCore, SlotOutcome
from edge_mapper.slot_planner import FrameObservations, SlotConfig
from tests.test_edge_core import F, K, ReturningDevice, _run
from twinslam.policies.registry import make_policy
from twinslam.slam.back_end.keyframe_archive import ArchivedKeyFrame, KeyFrameArchive
from twinslam.slam.back_end.keyframe_gate import KeyFrameGateConfig
from twinslam.slam.back_end.loop_closing import (
    SHARED_WORKER,
    YIELD_AT_MOST_S,
    LoopCloser,
    LoopJob,
    LoopQuery,
    SharedWorker,
    run_job,
)
from twinslam.slam.back_end.map_back_end import BackEndConfig
from twinslam.slam.keyframe import KeyFramePayload
from twinslam.slam.pose_plausibility import MotionBounds

#: metres a frame the device's pose estimate drifts along the wall on the way back
DRIFT_M = 0.005


class DriftingDevice(ReturningDevice):
    """The walk out and back along the wall; on the way back its keyframes' pose estimates
    drift DRIFT_M a frame (a tracker with nothing from the way out to hold on to)."""

    def keyframe(self, frame: int, slot: int, core: EdgeMapperCore) -> KeyFramePayload:
        kf = super().keyframe(frame, slot, core)
        kf.pose[0, 3] += DRIFT_M * max(0, frame - self.turn)
        return kf


def _edge(loops: bool, checkpoint: Path | None = None, reach_m: float | None = None,
          confirmations: int = 0) -> EdgeMapperCore:
    """V_max 4, no restores (the way out is in the archive only); a loop joins keyframes 40
    frames apart (the walk is 128 frames long), closed in finish_slot itself; ``reach_m``:
    the correction a device accepts on a map swap, if not the default; ``confirmations``:
    later keyframes that must find the place again (0: the first keyframe that finds it
    closes the loop, which these tests of the graph look at)."""
    gate = KeyFrameGateConfig() if reach_m is None else \
        KeyFrameGateConfig(dataclasses.replace(MotionBounds(), correction_m=reach_m))
    return EdgeMapperCore(make_policy("lff"), K,
                          EdgeConfig(slot=SlotConfig(vmax=4), back_end=BackEndConfig(
                              loop_closing=loops, loop_background=False, loop_min_gap=40,
                              loop_confirmations=confirmations, keyframe_gate=gate)),
                          checkpoint)


def _errors(core: EdgeMapperCore, device: ReturningDevice) -> dict[int, float]:
    """Each managed keyframe's distance from where it truly was (m)."""
    return {k: float(np.linalg.norm(kf.pose[:3, 3] - device.pose(k)[:3, 3]))
            for k, kf in core.map.keyframes.items()}


def _point_error(core: EdgeMapperCore, device: ReturningDevice) -> float:
    """Mean distance of the map's points from the nearest wall corner (m)."""
    return float(np.mean([np.linalg.norm(device.world - p.position, axis=1).min()
                          for p in core.map.points.values()]))


def _walk_until_a_loop(core: EdgeMapperCore, device: ReturningDevice, slots: int = 16
                       ) -> SlotOutcome | None:
    for slot in range(slots):
        out = _run(core, device, range(slot, slot + 1), rates=[20.0])[0]
        if out.loop is not None:
            return out
    return None


def test_the_edge_closes_a_loop_and_takes_the_drift_out_of_the_map() -> None:
    """The loop closes from the first keyframe of the way back that sees the way out's
    places, with the way-out keyframe that stood nearest (within 0.3 m in truth); the new
    keyframe drifted 15 cm and is put back where that keyframe's view puts it (within its
    own error of the way out, under 3 cm), the keyframes around it, tracked on common
    ground, stay where they were (within 3 cm, as without a loop), and the map's points come
    back to the wall. Without loop closing the same slot keeps the drift."""
    device = DriftingDevice(np.random.default_rng(3), 8 * F)
    core = _edge(loops=True)
    out = _walk_until_a_loop(core, device)
    assert out is not None and core.loops_closed == 1, "no loop closed on the way back"
    assert out.loop is not None and not out.loop.refused
    loop = out.loop
    assert loop is not None and loop.new > device.turn and loop.new - loop.old >= 40
    assert loop.inliers >= 100 and loop.moved_m > 0.1
    assert out.timings_ms["loop"] >= 0.0 and loop.worker_ms > 0.0

    plain, same = _edge(loops=False), DriftingDevice(np.random.default_rng(3), 8 * F)
    for slot in range(out.slot + 1):
        _run(plain, same, range(slot, slot + 1), rates=[20.0])
    assert sorted(plain.map.keyframes) == sorted(core.map.keyframes)
    drifted, closed = _errors(plain, same), _errors(core, device)
    assert drifted[loop.new] > 0.1
    truth = device.pose
    assert np.linalg.norm(truth(loop.old)[:3, 3] - truth(loop.new)[:3, 3]) < 0.3, loop.old
    place = core.back_end.archive.get(loop.old).pose
    inherited = float(np.linalg.norm(place[:3, 3] - truth(loop.old)[:3, 3]))
    assert closed[loop.new] < min(inherited + 0.005, 0.03), (closed, inherited)
    assert max(closed.values()) < 0.03, closed
    assert _point_error(core, device) < 0.5 * _point_error(plain, same)


def test_an_edge_that_pauses_its_loop_search_closes_no_loop_and_resumes_from_its_newest(
        ) -> None:
    """An edge over its compute budget starts no loop search (its worker's CPU goes to the
    slots): the walk back runs paused past the slot where the loop closes, and none closes;
    resumed, the next slot's end looks from the newest keyframes the map integrated and
    closes it with the same place."""
    device = DriftingDevice(np.random.default_rng(3), 8 * F)
    reference = _edge(loops=True)
    first = _walk_until_a_loop(reference, device)
    assert first is not None
    device = DriftingDevice(np.random.default_rng(3), 8 * F)
    core = _edge(loops=True)
    core.set_loop_search(False)
    for slot in range(first.slot + 2):
        out = _run(core, device, range(slot, slot + 1), rates=[20.0])[0]
        assert out.loop is None
    assert core.loops_closed == 0 and not core.back_end.loop_closer.job_seconds
    core.set_loop_search(True)
    slot = first.slot + 2
    out = _run(core, device, range(slot, slot + 1), rates=[20.0])[0]
    assert core.loops_closed == 0                  # the search starts at this slot's end
    out = _run(core, device, range(slot + 1, slot + 2), rates=[20.0])[0]
    assert out.loop is not None and not out.loop.refused and core.loops_closed == 1
    assert first.loop is not None and out.loop.old == first.loop.old    # the same place


def test_a_loop_that_would_move_the_map_beyond_a_devices_reach_is_refused() -> None:
    """A device accepts a map that moved at most ``correction_m`` under it; a loop whose
    corrections go farther (here: 15 cm against a reach of 5 cm) is refused and counted, the
    map left as it was."""
    device = DriftingDevice(np.random.default_rng(3), 8 * F)
    core = _edge(loops=True, reach_m=0.05)
    out = _walk_until_a_loop(core, device)
    assert out is not None and out.loop is not None
    assert "more than 0.05 m" in out.loop.refused and out.loop.moved_m > 0.1
    assert core.loops_closed == 0 and core.loops_refused == 1
    assert _errors(core, device)[out.loop.new] > 0.1          # the drift stays


def test_the_loop_corrected_map_and_archive_survive_a_restart(tmp_path: Path) -> None:
    """A loop's corrections reach the checkpoint: an edge restarted from it holds the
    corrected keyframes, counts the loop, keeps it for the next loop's graph, and reads back
    an archived keyframe the loop moved as moved. The keyframe trajectory (map and archive,
    by capture time) is the corrected one, before the restart and after."""
    device = DriftingDevice(np.random.default_rng(3), 8 * F)
    checkpoint = tmp_path / "edge.npz"
    core = _edge(loops=True, checkpoint=checkpoint)
    out = _walk_until_a_loop(core, device)
    assert out is not None and out.loop is not None
    again = _edge(loops=True, checkpoint=checkpoint)
    assert again.loops_closed == 1
    assert [(e.old, e.new, e.inliers) for e in again.loop_edges] == \
        [(out.loop.old, out.loop.new, out.loop.inliers)]    # as stiff as it was measured
    np.testing.assert_allclose(again.loop_edges[0].measured, core.loop_edges[0].measured)
    for k, kf in core.map.keyframes.items():
        np.testing.assert_allclose(again.map.keyframes[k].pose, kf.pose, atol=1e-9)
    trajectory = core.back_end.keyframe_trajectory()
    kept = {**{kf.id: kf.pose for kf in core.archive},
            **{k: kf.pose for k, kf in core.map.keyframes.items()}}
    assert len(core.archive) > 0 and len(trajectory) == len(kept)
    # capture times 0.1 s a frame, oldest first; each keyframe where the edge holds it now
    assert [round(t / 0.1) for t, _ in trajectory] == sorted(kept)
    for t, pose in trajectory:
        np.testing.assert_array_equal(pose, kept[round(t / 0.1)])
    for (t, pose), (t_again, pose_again) in zip(
            trajectory, again.back_end.keyframe_trajectory(), strict=True):
        assert t_again == t
        np.testing.assert_allclose(pose_again, pose, atol=1e-9)
    # a correction of an archived keyframe is written to the archive's pose file
    some = next(iter(core.archive))
    shift = np.eye(4)
    shift[:3, 3] = (0.0, 0.02, 0.0)
    assert core.archive.correct({some.id: shift}) == [some.id]
    reread = _edge(loops=True, checkpoint=checkpoint).archive.get(some.id)
    up = np.array([0.0, 0.02, 0.0])
    np.testing.assert_allclose(reread.pose[:3, 3], some.pose[:3, 3] + up)
    np.testing.assert_allclose(reread.positions, some.positions + up)
    # a sub-millimetre one is not worth recording
    shift[:3, 3] = (0.0, 0.0002, 0.0)
    assert core.archive.correct({some.id: shift}) == []


def _archive_disagreement(core: EdgeMapperCore, device: ReturningDevice) -> float:
    """The largest error, against the truth's, of the relative position of an archived and a
    managed keyframe that truly stand within 0.3 m of each other (m; 0 without such pairs):
    how far the archive's copy of a place lies from the map's."""
    errors = [0.0]
    for archived in core.archive:
        for k, kf in core.map.keyframes.items():
            truth_a, truth_k = device.pose(archived.id), device.pose(k)
            if np.linalg.norm(truth_a[:3, 3] - truth_k[:3, 3]) > 0.3:
                continue
            seen = np.linalg.inv(archived.pose) @ kf.pose
            true = np.linalg.inv(truth_a) @ truth_k
            errors.append(float(np.linalg.norm(seen[:3, 3] - true[:3, 3])))
    return max(errors)


def test_archive_and_map_agree_after_evictions_restores_and_a_loop() -> None:
    """The drifting walk out and back with V_max 4: the way out is evicted into the archive,
    the way back restores archived keyframes where the camera heads and drifts 5 mm a frame.
    Before the loop the archive and the map disagree by the drift (over 20 cm); once the
    loop closes (confirmed by later keyframes, the default) every archived keyframe lies
    where the map's keyframes of its place put it, within the keyframes' own noise (5 cm)."""
    spread = {}
    for loops in (True, False):
        device = DriftingDevice(np.random.default_rng(3), 8 * F)
        core = EdgeMapperCore(make_policy("lff"), K, EdgeConfig(
            slot=SlotConfig(vmax=4), restore_keyframes=2, back_end=BackEndConfig(
                loop_closing=loops, loop_background=False, loop_min_gap=40)))
        outs = [_run(core, device, range(slot, slot + 1), rates=[20.0])[0]
                for slot in range(16)]
        assert any(o.restored for o in outs) and any(o.evicted for o in outs)
        spread[loops] = _archive_disagreement(core, device)
        assert core.loops_closed == int(loops)
    assert spread[False] > 0.2 and spread[True] < 0.05, spread


def _job(device: ReturningDevice) -> LoopJob:
    """An archive of the way out (true poses, points at their corners) and one frame of the way
    back, 60 frames later, at the place of frame 30, whose pose drifted 10 cm."""
    archive = KeyFrameArchive(100)
    poses = {}
    for kf in range(0, 64, 8):
        seen, uv, depth, _ = device.observe(kf, EdgeMapperCore(make_policy("lff"), K))
        measurements = np.column_stack([uv, depth])
        archive.add(ArchivedKeyFrame(kf, device.pose(kf), seen.astype(np.int64) + 1,
                                     device.world[seen], device.descs[seen], measurements, 0))
        poses[kf] = device.pose(kf)
    frame = 2 * device.turn - 30
    seen, uv, _, _ = device.observe(frame, EdgeMapperCore(make_policy("lff"), K))
    poses[frame] = device.pose(frame) @ np.array([[1, 0, 0, 0.1], [0, 1, 0, 0], [0, 0, 1, 0],
                                                  [0, 0, 0, 1.0]])
    return LoopJob((LoopQuery(frame, uv, device.descs[seen]),), archive, poses, K,
                   {frame: frozenset((seen + 1).tolist())})


def test_the_worker_thread_answers_as_the_caller_would_and_takes_one_job_at_a_time() -> None:
    device = ReturningDevice(np.random.default_rng(5), 64)
    job = _job(device)
    inline = LoopCloser(background=False, min_gap=40, confirmations=0)
    worker = LoopCloser(min_gap=40, confirmations=0)
    try:
        assert inline.submit(job) and worker.submit(job)
        assert not worker.submit(job)                 # one job at a time, until taken
        here, there = inline.take(), worker.take(wait_s=30.0)
        assert here is not None and there is not None
        assert here.candidate.old == there.candidate.old and here.closure is not None
        assert there.closure is not None
        for k, pose in here.closure.poses.items():
            np.testing.assert_allclose(there.closure.poses[k], pose, atol=1e-9)
        assert worker.take() is None and worker.submit(job)    # taken: the next one may start
        last = worker.take(wait_s=30.0)
        assert last is not None
        # each job taken leaves the worker's time on it (what bench.map_consistency reports)
        assert list(worker.job_seconds) == [there.seconds, last.seconds]
        assert list(inline.job_seconds) == [here.seconds] and here.seconds > 0
        # after a loop closes, the keyframes just after it look for none
        assert worker.wanted([job.queries[0].keyframe + 1, job.queries[0].keyframe + 500]) \
            == [job.queries[0].keyframe + 500]
    finally:
        worker.close()


def _way_out_archive(device: ReturningDevice) -> tuple[KeyFrameArchive, dict[int, np.ndarray]]:
    """The way out's keyframes (every 8th frame of 64) archived at their true poses."""
    archive, poses = KeyFrameArchive(100), {}
    for kf in range(0, 64, 8):
        seen, uv, depth, _ = device.observe(kf, EdgeMapperCore(make_policy("lff"), K))
        archive.add(ArchivedKeyFrame(kf, device.pose(kf), seen.astype(np.int64) + 1,
                                     device.world[seen], device.descs[seen],
                                     np.column_stack([uv, depth]), 0))
        poses[kf] = device.pose(kf)
    return archive, poses


def _looking_at(device: ReturningDevice, frame: int, query: int) -> LoopQuery:
    """Keyframe ``query`` seeing what the camera saw at ``frame`` of the walk."""
    seen, uv, _, _ = device.observe(frame, EdgeMapperCore(make_policy("lff"), K))
    return LoopQuery(query, uv, device.descs[seen])


def _new_ground(query: int, rng: np.random.Generator) -> LoopQuery:
    """Keyframe ``query`` looking at a place the archive never saw."""
    return LoopQuery(query, rng.uniform([5, 5], [635, 475], (300, 2)),
                     rng.integers(0, 256, (300, 32), dtype=np.uint8))


def _moved(pose: np.ndarray, dx: float) -> np.ndarray:
    out = pose.copy()
    out[0, 3] += dx
    return out


def test_a_loop_closes_once_later_keyframes_find_the_place_again() -> None:
    """Three keyframes of the way back see the way out's places, their poses 10 cm off: the
    loop closes from the third (ORB-SLAM3's temporal consistency), not before."""
    device = ReturningDevice(np.random.default_rng(5), 64)
    archive, poses = _way_out_archive(device)
    queries = [_looking_at(device, frame, q) for frame, q in ((30, 200), (28, 202), (26, 204))]
    for q, frame in zip((200, 202, 204), (30, 28, 26), strict=True):
        poses[q] = _moved(device.pose(frame), 0.1)
    closer = LoopCloser(background=False, min_gap=40)
    for n in (1, 2):                               # one keyframe a job: not yet
        assert closer.submit(LoopJob(tuple(queries[:n][-1:]), archive, poses, K, {}))
        result = closer.take()
        assert result is not None and result.candidate.found and result.closure is None
    assert closer.submit(LoopJob((queries[2],), archive, poses, K, {}))
    result = closer.take()
    assert result is not None and result.query == 204 and result.closure is not None
    corrected = result.closure.poses[204][:3, 3]
    assert np.linalg.norm(corrected - device.pose(26)[:3, 3]) < 0.02


def test_a_look_alike_place_one_keyframe_finds_is_refused_by_the_next_ones() -> None:
    """A keyframe of the way back sees a poster that also hangs on the way out — its
    features are those the camera saw at frame 30, while it is 30 cm from there (within the
    drift a walk can have gathered); the next two keyframes look at ground the archive never
    saw. The candidate is dropped: no loop closes, the map is not bent to the look-alike."""
    rng = np.random.default_rng(9)
    device = ReturningDevice(np.random.default_rng(5), 64)
    archive, poses = _way_out_archive(device)
    poses[200] = _moved(device.pose(30), 0.3)
    poses[202], poses[204] = _moved(device.pose(29), 0.3), _moved(device.pose(28), 0.3)
    closer = LoopCloser(background=False, min_gap=40)
    results = []
    for query in (_looking_at(device, 30, 200), _new_ground(202, rng), _new_ground(204, rng)):
        assert closer.submit(LoopJob((query,), archive, poses, K, {}))
        results.append(closer.take())
    assert results[0] is not None and results[0].candidate.found     # the poster fooled one
    assert all(r is not None and r.closure is None for r in results)
    assert closer.confirmation.dropped == 1 and closer.confirmation.pending is None
    # without the confirmation the first keyframe would have closed it
    eager = LoopCloser(background=False, min_gap=40, confirmations=0)
    assert eager.submit(LoopJob((_looking_at(device, 30, 200),), archive, poses, K, {}))
    taken = eager.take()
    assert taken is not None and taken.closure is not None


def test_a_loop_farther_than_the_walk_can_have_drifted_is_refused() -> None:
    """The same poster seen 2 m from where it hangs, after a walk of 6 m from there: the loop
    would call 2 m drift, more than 10 cm + 5 % of the walk; refused even where the first
    keyframe that finds a place closes it."""
    device = ReturningDevice(np.random.default_rng(5), 64)
    archive, poses = _way_out_archive(device)
    poses[200] = _moved(device.pose(30), 2.0)
    closer = LoopCloser(background=False, min_gap=40, confirmations=0)
    assert closer.submit(LoopJob((_looking_at(device, 30, 200),), archive, poses, K, {}))
    result = closer.take()
    assert result is not None and result.closure is None and not result.candidate.found
    assert "can have drifted" in result.candidate.reason


def test_a_loop_job_that_fails_is_reported_and_the_slots_go_on(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """A loop closer that raises (here: its place recognition) is reported in the slot's
    outcome, which the edge logs, and the edge's slots go on without a loop."""
    def broken(*args: object, **kwargs: object) -> None:
        raise RuntimeError("the index is corrupt")
    monkeypatch.setattr("twinslam.slam.back_end.loop_closing.detect_loop", broken)
    device = DriftingDevice(np.random.default_rng(3), 8 * F)
    core = _edge(loops=True)
    outs = [_run(core, device, range(slot, slot + 1), rates=[20.0])[0] for slot in range(16)]
    failed = [o.loop for o in outs if o.loop is not None]
    assert failed, "no loop job ran"
    assert all(f.old == -1 and "RuntimeError: the index is corrupt" in f.refused
               for f in failed)
    assert core.loops_closed == 0 and len(core.map.keyframes) <= 4


def test_the_archive_poses_the_worker_could_not_write_are_reported_once(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Writing a moved archive's poses happens beside the slots; when it fails (a full disk)
    the slot's outcome says so, which the edge logs as an error, once; the map keeps its
    move and the slots go on. (This walk's loop moves no archived keyframe: the way out it
    holds is where the loop anchors. A merge's move of the whole map moves them all.)"""
    def full(self: KeyFrameArchive, *args: object, **kwargs: object) -> None:
        raise OSError(28, "No space left on device")
    monkeypatch.setattr(KeyFrameArchive, "save_poses", full)
    device = DriftingDevice(np.random.default_rng(3), 8 * F)
    core = _edge(loops=True, checkpoint=tmp_path / "edge.npz")
    out = _walk_until_a_loop(core, device)
    assert out is not None and out.loop is not None and not out.loop.refused
    assert core.loops_closed == 1 and _errors(core, device)[out.loop.new] < 0.03
    assert out.loop_failures == []
    before = {kf.id: kf.pose for kf in core.archive}
    shift = np.eye(4)
    shift[:3, 3] = (0.1, 0.0, 0.0)
    core.align(shift)                                   # as a merge moves the map
    moved = _run(core, device, range(out.slot + 1, out.slot + 2), rates=[20.0])[0]
    assert before and all(np.allclose(kf.pose, shift @ before[kf.id])
                          for kf in core.archive if kf.id in before)
    assert len(moved.loop_failures) == 1
    assert "aligned archive" in moved.loop_failures[0]
    assert "No space left on device" in moved.loop_failures[0]
    after = _run(core, device, range(out.slot + 2, out.slot + 3), rates=[20.0])[0]
    assert after.loop_failures == []


def test_work_the_worker_fails_beside_the_slots_is_kept_until_taken() -> None:
    """On the worker thread too, a failure of work handed to ``after`` is not lost in its
    future: ``failures`` gives it once, after the work ran."""
    closer = LoopCloser()
    try:
        closer.after(lambda: 1 / 0, "dividing")
        closer.after(lambda: None, "nothing")
    finally:
        closer.close()                                # waits for the queued work
    assert closer.failures() == ["dividing failed: ZeroDivisionError: division by zero"]
    assert closer.failures() == []


def test_closing_drops_a_loop_search_not_started_and_writes_the_files_queued() -> None:
    """At the edge's stop each closer is closed before the process ends without waiting for
    the worker: the archive's poses of a correction queued beside the slots are written, a
    loop search still waiting for the worker is dropped (its answer would reach no map)."""
    device = ReturningDevice(np.random.default_rng(5), 64)
    closer = LoopCloser(min_gap=40, confirmations=0)
    ran: list[str] = []
    release = threading.Event()
    closer.after(lambda: (release.wait(30.0), ran.append("held")), "holding the worker")
    assert closer.submit(_job(device))               # queued behind the hold
    closer.after(lambda: ran.append("files"), "files")
    threading.Timer(0.2, release.set).start()
    try:
        closer.close()
    finally:
        release.set()
    assert ran == ["held", "files"]
    assert closer.take() is None and not closer.busy     # the search never ran


class LaggingDevice(DriftingDevice):
    """The drifting walk, its summaries saying which map version each frame was tracked on
    (``tracked_on``; -1: unknown): the map a loop corrected reaches a device a slot or two
    after the slot that closed it, and the frames it tracks meanwhile are posed on the map
    before the correction — with that map's drift, which stops growing from ``held_from`` on
    (the frame the loop was closed from: the old map is all the device tracks on)."""

    tracked_on = -1
    held_from: int | None = None

    def summary(self, frame: int, core: EdgeMapperCore) -> FrameObservations:
        return dataclasses.replace(super().summary(frame, core), map_version=self.tracked_on)

    def keyframe(self, frame: int, slot: int, core: EdgeMapperCore) -> KeyFramePayload:
        kf = super().keyframe(frame, slot, core)
        if self.held_from is not None and frame > self.held_from:
            kf.pose[0, 3] -= DRIFT_M * (frame - self.held_from)
        return kf


def test_keyframes_tracked_on_the_map_before_a_loop_enter_the_corrected_map_corrected() -> None:
    """The slot after a loop: the device still tracks on the map before the correction (its
    update is on the way), so its keyframes carry the drift the loop took out. The edge knows
    which version each frame was tracked on and moves them by the corrections since: they
    enter the corrected map where the corrected walk is, not a loop's drift away; an edge that
    does not know the version (-1) takes them as they come, and its keyframe gate refuses
    them (their map points no longer reproject where they were seen): the slot's uploads are
    lost."""
    errors, refused = {}, {}
    for knows in (True, False):
        device = LaggingDevice(np.random.default_rng(3), 8 * F)
        core = _edge(loops=True)
        out = _walk_until_a_loop(core, device)
        assert out is not None and out.loop is not None and core.loops_closed == 1
        moved = core.frame_correction
        assert np.linalg.norm(moved[:3, 3]) > 0.1, "the loop corrected no drift at the head"
        device.tracked_on = out.version - 1 if knows else -1    # the map before the loop
        device.held_from = out.loop.new
        after = _run(core, device, range(out.slot + 1, out.slot + 2), rates=[20.0])[0]
        new = [k for k in core.map.keyframes if k >= (out.slot + 1) * F]
        refused[knows] = sorted(after.refused)
        errors[knows] = max((float(np.linalg.norm(core.map.keyframes[k].pose[:3, 3]
                                                  - device.pose(k)[:3, 3])) for k in new),
                            default=np.inf)
    # the corrected walk stands where the way out's keyframes put it (each up to 2–3 cm off
    # in this walk); uncorrected, the keyframes would be the loop's 15 cm away
    assert not refused[True] and errors[True] < 0.04, (refused, errors)
    assert refused[False] or errors[False] > 0.1, (refused, errors)


def test_the_loop_closers_of_a_process_queue_on_one_worker_first_come_first_served() -> None:
    """An edge's devices close their loops on one worker thread, in the order their work came
    (their slot thread keeps the rest of the interpreter): two closers' jobs and work run on
    the same thread, one after the other, and each closer's answer is its own job's; closing
    one waits for its own work only."""
    device = ReturningDevice(np.random.default_rng(5), 64)
    job = _job(device)
    first, second = LoopCloser(min_gap=40, confirmations=0), LoopCloser(min_gap=40,
                                                                      confirmations=0)
    ran: list[tuple[str, int]] = []
    release = threading.Event()
    try:
        first.after(lambda: (release.wait(30.0), ran.append(("held", threading.get_ident()))),
                    "holding the worker")
        assert first.submit(job) and second.submit(job)
        second.after(lambda: ran.append(("second's files", threading.get_ident())), "files")
        assert first.take() is None and second.take() is None    # queued behind the hold
        release.set()
        one, two = first.take(wait_s=30.0), second.take(wait_s=30.0)
        assert one is not None and two is not None
        assert one.candidate.old == two.candidate.old and one.closure is not None
        second.close()
        assert [what for what, _ in ran] == ["held", "second's files"]
        assert len({thread for _, thread in ran}) == 1            # one worker thread
    finally:
        release.set()
        first.close()
        second.close()


@pytest.mark.skipif(not sys.platform.startswith("linux"),
                    reason="a thread's own nice value is Linux's")
def test_the_loop_worker_runs_below_the_slots_priority_and_the_caller_keeps_its_own() -> None:
    """Every device's loop jobs run on one worker ``niceness`` steps below the thread that
    started it (a loop may wait a slot, a map may not): the worker's own nice value is the
    starter's plus the steps, the starter's unchanged; 0 keeps the same priority, and a
    niceness outside 0-19 is refused."""
    own = os.getpriority(os.PRIO_PROCESS, 0)          # this thread's (Linux: per thread)
    for steps in (7, 0):
        worker = SharedWorker(niceness=steps)
        try:
            seen = worker.submit(os.getpriority, os.PRIO_PROCESS, 0).result(timeout=30)
            # and top -H, ps -L show it by its name, not the process's
            shown = worker.submit(lambda: Path(
                f"/proc/self/task/{threading.get_native_id()}/comm").read_text()).result(30)
        finally:
            worker.stop()
        assert seen == worker.nice == min(19, own + steps)
        assert shown.strip() == "loop-closer_0"
        assert os.getpriority(os.PRIO_PROCESS, 0) == own
    worker = SharedWorker()
    for bad in (-1, 20):
        with pytest.raises(ValueError, match="0 to 19"):
            worker.lower_priority(bad)
    worker.lower_priority(3)
    assert worker.niceness == 3


def test_the_loop_workers_queue_runs_the_loops_work_before_the_place_looks() -> None:
    """Work queued ``after_loops`` (the place looks, the keyframe database's filing) waits
    while loop work is queued: a loop job submitted behind three looks runs before them, and
    each kind keeps its order (a correction's files follow the job that made them). A look
    cancelled before it starts never runs; an error reaches the caller's future."""
    worker = SharedWorker()
    ran: list[str] = []
    release = threading.Event()
    try:
        held = worker.submit(release.wait, 30)             # the worker busy meanwhile
        looks = [worker.submit(ran.append, f"look {i}", after_loops=True) for i in range(3)]
        dropped = worker.submit(ran.append, "cancelled look", after_loops=True)
        loops = [worker.submit(ran.append, what) for what in ("loop job", "its files")]
        failing = worker.submit(operator.truediv, 1, 0)
        assert dropped.cancel()
        release.set()
        for future in (held, *looks, *loops):
            future.result(timeout=30)
        with pytest.raises(ZeroDivisionError):
            failing.result(timeout=30)
    finally:
        worker.stop()
    assert ran == ["loop job", "its files", "look 0", "look 1", "look 2"]
    assert dropped.cancelled() and worker.overdue == 0


def _held_worker(look_bound_s: float) -> tuple[SharedWorker, threading.Event, Future[Any]]:
    """A loop worker whose looks wait ``look_bound_s`` at most, busy with work that runs until
    the event is set (what is queued meanwhile waits); the work's future."""
    worker = SharedWorker()
    worker.after_loops_at_most_s = look_bound_s
    release = threading.Event()
    return worker, release, worker.submit(release.wait, 30)


def test_a_place_look_that_waited_past_its_bound_goes_before_the_loops_that_keep_coming(
        ) -> None:
    """Work queued after the loops waits at most ``after_loops_at_most_s`` while loop work
    keeps coming: past it, it goes next, before the loop work queued while it waited (on a
    host the loops keep busy, devices still merge)."""
    worker, release, held = _held_worker(look_bound_s=0.2)
    ran: list[str] = []
    try:
        look = worker.submit(ran.append, "look", after_loops=True)
        loops = [worker.submit(ran.append, f"loop {i}") for i in range(2)]
        time.sleep(0.4)                          # the look waits past its bound
        assert worker.waiting() == (2, 1) and worker.overdue == 0
        release.set()
        for future in (held, look, *loops):
            future.result(timeout=30)
    finally:
        worker.stop()
    assert ran == ["look", "loop 0", "loop 1"]
    assert worker.waiting() == (0, 0) and worker.overdue == 1     # counted for /diagnostics


def test_cancelled_work_is_neither_waiting_nor_counted_overdue() -> None:
    """A look cancelled while it waited (its device forgotten, the edge closing) leaves the
    count of work waiting at once, is not counted overdue when its turn would have come past
    its bound, and the work queued behind it runs as before: /diagnostics tells of the
    work the worker still owes."""
    worker, release, held = _held_worker(look_bound_s=0.2)
    ran: list[str] = []
    try:
        look = worker.submit(ran.append, "look", after_loops=True)
        loop = worker.submit(ran.append, "loop")
        time.sleep(0.4)                          # the look waits past its bound...
        assert look.cancel()                     # ...and is cancelled before its turn
        assert worker.waiting() == (1, 0)
        release.set()
        held.result(timeout=30)
        loop.result(timeout=30)
        later = worker.submit(ran.append, "later", after_loops=True)
        later.result(timeout=30)
    finally:
        worker.stop()
    assert ran == ["loop", "later"] and look.cancelled()
    assert worker.waiting() == (0, 0) and worker.overdue == 0


def test_the_loop_worker_takes_at_most_its_share_of_a_core() -> None:
    """With ``share`` s, each piece of work on the loop worker is followed by a rest of its
    CPU time × (1 − s) / s before the next starts (the slots keep the rest of the core);
    with the whole core it never rests. A share outside (0, 1] is refused."""

    def burn(seconds: float) -> tuple[float, float, float]:
        """Busy for ``seconds`` of this thread's CPU; (start, end, CPU used)."""
        start, cpu = time.monotonic(), time.thread_time()
        while time.thread_time() - cpu < seconds:
            pass
        return start, time.monotonic(), time.thread_time() - cpu

    for share in (0.25, 1.0):
        worker = SharedWorker(share=share)
        try:
            first = worker.submit(burn, 0.05)
            second = worker.submit(burn, 0.01)
            (_, first_end, used), (second_start, _, _) = (first.result(timeout=60),
                                                         second.result(timeout=60))
        finally:
            worker.stop()
        if share < 1:
            assert second_start - first_end >= used * (1 - share) / share * 0.99
            assert worker.rested_s > 0
        else:
            assert worker.rested_s == 0
    for bad in (0.0, -0.5, 1.5):
        with pytest.raises(ValueError, match="share of a core"):
            SharedWorker().limit_share(bad)


def test_the_loop_worker_waits_while_the_slots_work_runs_and_never_longer_than_its_bound(
        ) -> None:
    """Yielding, the worker does not start a query while a slot callback runs: it goes on
    once the slots' work ends, after YIELD_AT_MOST_S at the latest (the loops are delayed,
    never starved), and not at all when nothing runs or yielding is off."""
    worker = SharedWorker()
    worker.yield_to_slots(True)
    started = threading.Event()
    ended = 0.0

    def slot(seconds: float) -> None:
        nonlocal ended
        with worker.slot_work():
            started.set()
            time.sleep(seconds)
            ended = time.monotonic()

    t = threading.Thread(target=slot, args=(0.2,))
    t.start()
    assert started.wait(10)
    worker.wait_for_slots()                   # waits for the callback to end
    assert time.monotonic() >= ended > 0 and worker.yielded_s > 0.05
    t.join()
    before = worker.yielded_s
    worker.wait_for_slots()                   # nothing runs: no wait
    assert worker.yielded_s == before
    started.clear()
    t = threading.Thread(target=slot, args=(YIELD_AT_MOST_S + 1.0,))
    t.start()
    assert started.wait(10)
    began = time.monotonic()
    worker.wait_for_slots()                   # a long callback: the bound, not its end
    waited = time.monotonic() - began
    assert YIELD_AT_MOST_S * 0.9 <= waited < YIELD_AT_MOST_S + 0.9
    worker.yield_to_slots(False)
    began = time.monotonic()
    worker.wait_for_slots()                   # not yielding: runs at once
    assert time.monotonic() - began < 0.1
    t.join()


def test_a_loop_job_pauses_for_the_slots_before_each_query() -> None:
    """The job asks its pause before every query and before the pose graph, and finds the
    same loop as without pauses."""
    device = ReturningDevice(np.random.default_rng(5), 64)
    job = _job(device)
    pauses: list[float] = []
    paused = run_job(job, 40, None, lambda: pauses.append(time.monotonic()))
    plain = run_job(job, 40, None)
    assert paused.closure is not None and plain.closure is not None
    assert paused.candidate.old == plain.candidate.old and paused.query == plain.query
    queries_looked = sorted(q.keyframe for q in job.queries).index(paused.query) + 1
    assert len(pauses) == queries_looked + 1        # each query looked at, then the graph


def test_a_loop_jobs_time_leaves_out_its_waits_for_the_slots() -> None:
    """The job's seconds are its own work: a pause that waits 0.2 s before each query and
    the graph is counted apart (``waited``), not in the time the edge reports as the loop
    closer's."""
    device = ReturningDevice(np.random.default_rng(5), 64)
    job = _job(device)
    pauses: list[float] = []

    def slow_slots() -> None:
        pauses.append(time.monotonic())
        time.sleep(0.2)

    began = time.monotonic()
    result = run_job(job, 40, None, slow_slots)
    wall = time.monotonic() - began
    assert result.closure is not None and len(pauses) >= 2
    assert result.waited >= 0.2 * len(pauses)
    assert abs(result.seconds + result.waited - wall) < 0.05
    assert result.seconds < wall - 0.2 * len(pauses) + 0.05


def test_a_slot_callback_that_drops_the_running_job_is_not_waited_for_by_it() -> None:
    """A merge drops the running loop job from inside a device's callback (the slots' work):
    while the callback waits for the job, its mark is lifted — else the job, waiting for the
    slots before each query, would wait for the callback that waits for it."""
    device = ReturningDevice(np.random.default_rng(5), 64)
    closer = LoopCloser(min_gap=40, confirmations=0)
    was = SHARED_WORKER.yields
    SHARED_WORKER.yield_to_slots(True)
    try:
        with SHARED_WORKER.slot_work():
            assert closer.submit(_job(device))
            before = SHARED_WORKER.yielded_s
            closer.discard()
            assert SHARED_WORKER.yielded_s - before < 0.1
            assert not SHARED_WORKER.slots_idle                  # the mark is back
        assert SHARED_WORKER.slots_idle
    finally:
        SHARED_WORKER.yield_to_slots(was)
        closer.close()



def test_a_slot_callback_taking_a_result_without_waiting_keeps_its_mark(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """``take()`` without a wait never blocks on the worker, so the callback's slot-work mark
    stays where it is: lifting it, even for a moment, could wake a worker waiting for the
    slots in the middle of the callback. Waiting for the job lifts it (as discard does)."""
    closer = LoopCloser(min_gap=40, confirmations=0)
    closer._running = Future()                           # a job still running
    changes: list[int] = []
    mark = SHARED_WORKER._mark
    monkeypatch.setattr(SHARED_WORKER, "_mark", lambda c: (changes.append(c), mark(c)))
    with SHARED_WORKER.slot_work():
        changes.clear()
        assert closer.take() is None
        assert changes == [] and not SHARED_WORKER.slots_idle
        assert closer.take(wait_s=0.01) is None
        assert changes == [-1, 1] and not SHARED_WORKER.slots_idle
    assert SHARED_WORKER.slots_idle
    closer._running = None
