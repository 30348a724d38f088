"""The edge's loop closer: place recognition and the pose graph on a worker thread, off the
slot's critical path, their answer applied between slots.

Each finished slot hands the closer the keyframes it integrated (their ORB features) with a
snapshot of what the edge knows: the archive's keyframes, the managed map's keyframes far
older than the query (restores bring old places back into the map, and a loop may close
with one of those), and every keyframe's pose. The worker looks for a loop
(:func:`~twinslam.slam.back_end.loop_detection.detect_loop`: place recognition, then PnP
with the gate's inliers) and, on one, solves the pose graph over archive ∪ managed keyframes
(:func:`~twinslam.slam.back_end.pose_graph.close_loop`). The snapshot shares nothing mutable
with the edge: archived keyframes never change in place, poses are copies. The next slot's
end takes the answer (:meth:`LoopCloser.take`) and applies it
(:mod:`twinslam.slam.back_end.loop_correction`): the map the device gets next is corrected.

``background=False`` runs the same work in the caller, for the offline pipelines whose
results must not depend on thread timing.
"""

from __future__ import annotations

import itertools
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from twinslam.slam.back_end.keyframe_archive import KeyFrameArchive
from twinslam.slam.back_end.keyframe_map import shared_counts
from twinslam.slam.back_end.loop_detection import MIN_GAP, LoopCandidate, detect_loop
from twinslam.slam.back_end.pose_graph import LoopClosure, LoopEdge, close_loop

#: after a loop closes at keyframe q, keyframes up to q + COOLDOWN ids look for none (the walk
#: goes on through the same place: each of them would find the loop just closed again)
COOLDOWN = 90


@dataclass(frozen=True)
class LoopQuery:
    """A keyframe the edge integrated, with what place recognition needs."""

    keyframe: int
    points_xy: np.ndarray        #: (n, 2) its ORB keypoints
    descriptors: np.ndarray      #: (n, 32) uint8
    #: (n,) the keypoints' depths, metres (0: none); None: a camera without depth
    depths: np.ndarray | None = None


@dataclass(frozen=True)
class LoopJob:
    queries: tuple[LoopQuery, ...]       #: newest first: the first loop found is closed
    archive: KeyFrameArchive             #: a snapshot (:meth:`KeyFrameArchive.snapshot`)
    poses: Mapping[int, np.ndarray]      #: every keyframe's camera-to-map, archive ∪ map
    intrinsics: np.ndarray
    #: the managed map's keyframes' map points (the archive's are in its snapshot)
    map_points: Mapping[int, frozenset[int]]
    #: the loops closed before, held by the new loop's graph too
    earlier: tuple[LoopEdge, ...] = ()


@dataclass(frozen=True)
class LoopResult:
    """What one job found: the loop and its pose graph's answer, or none."""

    candidate: LoopCandidate
    query: int                            #: the keyframe the loop was looked for from
    closure: LoopClosure | None
    seconds: float                        #: the worker's time on the job
    #: why the job failed (an exception in the search or the graph: the edge logs it and
    #: goes on without the loop); "": it did not
    error: str = ""


def guarded_job(job: LoopJob, min_gap: int = MIN_GAP) -> LoopResult:
    """:func:`run_job`, a failure reported in the result instead of raised: a loop closer
    that fails must not take the edge's slots down with it."""
    try:
        return run_job(job, min_gap)
    except Exception as exc:             # reported in the result, logged by the edge
        return LoopResult(LoopCandidate(-1, None, None, 0, "the loop job failed"),
                          job.queries[0].keyframe if job.queries else -1, None, 0.0,
                          f"{type(exc).__name__}: {exc}")


def run_job(job: LoopJob, min_gap: int = MIN_GAP) -> LoopResult:
    """Look for a loop from each query, newest first; close the first one found."""
    start = time.perf_counter()
    candidate, query = LoopCandidate(-1, None, None, 0, "no query"), -1
    for q in job.queries:
        candidate, query = detect_loop(job.archive, q.keyframe, q.points_xy, q.descriptors,
                                       job.intrinsics, min_gap, depths=q.depths), q.keyframe
        if candidate.found:
            break
    closure = None
    if candidate.found and candidate.measured is not None and query in job.poses:
        closure = close_loop(job.poses, candidate.old, query, candidate.measured,
                             shared_points(job), job.earlier)
    return LoopResult(candidate, query, closure, time.perf_counter() - start)


def shared_points(job: LoopJob) -> dict[tuple[int, int], int]:
    """The map points pairs of keyframes (a < b) of the job's graph share: each consecutive
    pair (by id: how stiff a step of the walk is, 0 included) and every other pair that
    shares any (the covisibility that holds keyframes seeing one place together)."""
    ids = sorted(job.poses)
    points = {k: np.fromiter(v, dtype=np.int64) for k, v in job.map_points.items()}
    for kf in job.archive:
        if kf.id not in points:
            points[kf.id] = np.unique(kf.point_ids.astype(np.int64))
    empty = np.zeros(0, dtype=np.int64)
    counts = shared_counts([points.get(k, empty) for k in ids])
    shared = {(a, b): 0 for a, b in itertools.pairwise(ids)}
    rows, cols = np.nonzero(np.triu(counts, 1))
    shared.update({(ids[i], ids[j]): int(counts[i, j])
                   for i, j in zip(rows.tolist(), cols.tolist(), strict=True)})
    return shared


class LoopCloser:
    """One loop job at a time, on a worker thread (or in the caller)."""

    def __init__(self, background: bool = True, min_gap: int = MIN_GAP,
                 cooldown: int = COOLDOWN) -> None:
        self.background = background
        self.min_gap = min_gap
        self.cooldown = cooldown
        self._executor: ThreadPoolExecutor | None = None
        self._running: Future[LoopResult] | None = None
        self._done: LoopResult | None = None
        self._quiet_until = -1           #: keyframe ids up to this look for no loop
        #: why work handed to :meth:`after` failed, until :meth:`failures` takes them (the
        #: worker appends, the slot takes: under the lock, none is lost between the two)
        self._failed: list[str] = []
        self._failed_lock = threading.Lock()

    @property
    def busy(self) -> bool:
        return self._running is not None and not self._running.done()

    def wanted(self, keyframes: Sequence[int]) -> list[int]:
        """Of ``keyframes``, those that may look for a loop now (not in a closed loop's
        cooldown)."""
        return [k for k in keyframes if k > self._quiet_until]

    def submit(self, job: LoopJob) -> bool:
        """Start ``job``; False (nothing started) while one runs or waits to be taken."""
        if self._running is not None or self._done is not None or not job.queries:
            return False
        if not self.background:
            self._done = guarded_job(job, self.min_gap)
            return True
        self._running = self._worker().submit(guarded_job, job, self.min_gap)
        return True

    def take(self, wait_s: float = 0.0) -> LoopResult | None:
        """The finished job's result (once), waiting up to ``wait_s`` for a running one; None
        while it runs or when none was started."""
        if self._running is not None:
            try:
                self._done = self._running.result(timeout=wait_s) if wait_s > 0 or \
                    self._running.done() else None
            except TimeoutError:
                return None
            if self._done is None:
                return None
            self._running = None
        done, self._done = self._done, None
        if done is not None and done.closure is not None:
            self._quiet_until = done.query + self.cooldown
        return done

    def after(self, work: Callable[[], object], what: str) -> None:
        """Run ``work`` (``what`` it does, for its failure's message) on the worker after what
        it has queued (in the caller without one): the archive's files of a correction,
        written beside the slots. Its failure (a full disk) is kept for :meth:`failures`, never
        raised: the edge's map is corrected already, and only the files lag behind it."""
        def guarded() -> None:
            try:
                work()
            except Exception as exc:         # reported by the edge's next slot
                with self._failed_lock:
                    self._failed.append(f"{what} failed: {type(exc).__name__}: {exc}")

        if not self.background:
            guarded()
            return
        self._worker().submit(guarded)

    def failures(self) -> list[str]:
        """What the work handed to :meth:`after` failed on since the last call (once each)."""
        with self._failed_lock:
            failed, self._failed = self._failed, []
        return failed

    def _worker(self) -> ThreadPoolExecutor:
        """The one worker thread, started with the first work it gets."""
        if self._executor is None:
            self._executor = ThreadPoolExecutor(1, thread_name_prefix="loop-closer")
        return self._executor

    def close(self) -> None:
        """Stop the worker (a running job finishes first)."""
        if self._executor is not None:
            self._executor.shutdown(wait=True)
            self._executor = None
