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

In a merged map (:mod:`~twinslam.slam.back_end.map_merging`) a query that finds no place
among the walk's own keyframes is looked for among the nearby keyframes of the devices that
joined the place before this one (:func:`loop_across`): a loop with one of them bends the
walk towards that device's keyframes, which the graph holds — one loop closing over the
place's keyframes, not one per device that only the merge's rigid motion relates.

``background=False`` runs the same work in the caller, for the offline pipelines whose
results must not depend on thread timing.

Every background loop closer of a process works on one worker thread, in the order the work
came: an edge serving many devices closes their loops one at a time beside its slot thread.
The edge's merge looks queue on it too (:mod:`edge_mapper.place_merging`): the process's
background work is one queue under the bounds below, in which the loops' work goes before
the looks' (``after_loops``: a look waits while a loop job is queued, AFTER_LOOPS_AT_MOST_S
at most). In one queue, in the order they came, twelve devices alone in their places on one
full core closed 29-31 of the 60 loops of a walk that comes back with ``merge_maps`` on, and
46-50 with it off; the loops first, 36-44 (docs/benchmarks/edge-scaling.md): a loop job
waited behind looks that found nothing, and a keyframe that leaves the map before its
device's next job starts is searched for no more
(:meth:`~twinslam.slam.back_end.map_back_end.MapBackEnd.start_loop_job`). Each device's own
thread let sixteen devices revisiting their places together run sixteen loop jobs at once
(place recognition, PnP, the pose graph: 30-110 ms a job on the 7-Scenes walk), on two cores
and against the slot thread for the interpreter: on one edge process their slots' work took
67-138 ms a device-slot there against 50-83 ms with loop closing off (``bench.edge_scaling
--devices 16``, docs/results/shared-map.md). A device's loop waits behind the others'
instead (its next job starts once its last was taken, so a device has one job in the queue
at most), and the slots keep their deadline.

The worker may run below the slot threads' priority (the edge node's
``loop_worker_niceness``, Linux nice steps: :meth:`SharedWorker.lower_priority`). Each job
takes every query its device gathered meanwhile, so the worker uses whatever the cores leave,
and on a host whose cores the edges fill it takes them from the slots: two edge processes on
a 2-core VM carried sixteen devices 36-38 % late at the same priority and 9-20 % late five or
ten steps below it — where no loop closed within the devices' 20-slot walk, against two to
eight at the same priority (``bench.edge_scaling --devices 16 --edges 2
--loop-worker-niceness 0,10``, docs/results/shared-map.md). On a walk that comes back for as
long as it went out (39 slots), twelve devices on two processes were 0-7 % late ten steps
below against 14-55 % at the same priority, and their loops closed a median two slots later
(24-36 of the 36 the same priority closed): the short walk had ended before the waiting jobs
ran. ``loop_worker_share`` caps the worker at a share of a core instead
(:meth:`SharedWorker.limit_share`: it rests after each job), on an idle host too, at the
slots' priority; on the longer walk a quarter of a core was late more often than ten nice
steps below (0.9-12.8 % against 0-7 %) and closed fewer loops, later. By default the worker
keeps the slots' priority and the whole core (the single device's host was measured so); an
edge host serving a dozen devices over several processes is better served ten steps below.

Within one process a nice value does not reach the interpreter the worker and the slot thread
share. By default (the edge's ``loop_worker_yields``) the worker waits before each query while
a slot callback runs (:meth:`SharedWorker.wait_for_slots`, at most YIELD_AT_MOST_S): eight
devices on one edge process walking a place and back were 0-15 % late instead of 33-49 % in
four paired rounds of five (in the fifth both were nearly on time), their loops closed in the
same slots, and one or two devices were unchanged.
"""

from __future__ import annotations

import itertools
import os
import threading
import time
from collections import deque
from collections.abc import Callable, Iterator, Mapping, Sequence
from concurrent.futures import Future, ThreadPoolExecutor, wait
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any, TypeVar

import numpy as np

from twinslam.rotations import rotation_angle_deg
from twinslam.slam.back_end.foreign_keyframes import (
    copy_anchors,
    keyframe_label,
    tag_of,
)
from twinslam.slam.back_end.keyframe_archive import KeyFrameArchive, point_id_sets
from twinslam.slam.back_end.keyframe_map import shared_pairs
from twinslam.slam.back_end.loop_detection import (
    MIN_GAP,
    LoopCandidate,
    detect_loop,
    recognise_place,
)
from twinslam.slam.back_end.place_index import KeptPlaceIndex
from twinslam.slam.back_end.pose_graph import Anchors, LoopClosure, LoopEdge, close_loop
from twinslam.slam.keyframe import KeyFramePayload
from twinslam.thread_names import name_this_thread
from twinslam.thread_priority import PER_THREAD_NICE, check_niceness, lower_this_thread

#: after a loop closes at keyframe q, keyframes up to q + COOLDOWN ids look for none (the walk
#: goes on through the same place: each of them would find the loop just closed again)
COOLDOWN = 90
#: later keyframes that must find a loop's place again, each put where the first detection's
#: correction puts it, before the loop closes (ORB-SLAM3 closes on three keyframes in all): a
#: poster that hangs in two rooms fools one keyframe, not the ones that look on past it
CONFIRMATIONS = 2
#: later keyframes that fail to find it so before a candidate is dropped (ORB-SLAM3: two)
MISSES = 2
#: two detections agree when the corrections they imply put the later keyframe within this
#: distance (m, plus DRIFT_RATE of the walk between the two) and angle (degrees) of each
#: other: a loop measured from depth is within 2.3 cm and 0.34° of the truth
#: (docs/results/map-consistency.md), the walk between two keyframes adds its drift
AGREE_M = 0.05
AGREE_DEG = 2.0
#: the drift a walk can have gathered, metres a metre walked: a loop implying more between its
#: two ends than DRIFT_SLACK_M + DRIFT_RATE × the walk's length between them is a look-alike
#: place, not drift (visual odometry drifts about 1 %; the default device's, 0.2-0.5 % on the
#: corridor)
DRIFT_RATE = 0.05
DRIFT_SLACK_M = 0.10
#: the worker's seconds of this many latest jobs are kept (what a bench reports)
JOB_TIMES_KEPT = 1000
#: a loop across devices (:func:`loop_across`) looks among the other devices' keyframes whose
#: cameras stand within this many metres of the query's and look within ACROSS_NEAR_DEG of its
#: way, as the two maps have them: the maps are in one frame already, a merge's alignment or
#: two walks' drift apart, so a place the query sees is one seen from nearby — and a
#: look-alike place elsewhere in the other map is never searched
ACROSS_NEAR_M = 1.0
ACROSS_NEAR_DEG = 45.0
#: ... and closes only when the other device's keyframe would move the query at least this
#: far (m) or turn it this much (degrees): a walk tracked on that device's keyframes agrees
#: with them already, and a loop measured from depth is itself within ~2 cm and 0.3° of the
#: truth (docs/results/map-consistency.md) — a smaller correction would move the map by its
#: measurement's noise, and its cooldown would hold back the loops that follow
ACROSS_MIN_M = 0.02
ACROSS_MIN_DEG = 0.5
#: ... and only with a copy the map adopted this many slots before the job: the other device
#: was there earlier (a map adopts another's keyframes at the slot end after that device
#: integrated them), as a loop of one walk joins its newer end to its older; where two
#: devices walk one place at once, neither bends towards the other's keyframes, which that
#: device's own walk moves meanwhile
ACROSS_GAP_SLOTS = 5


@dataclass(frozen=True)
class LoopQuery:
    """A keyframe the edge integrated, with what place recognition needs."""

    keyframe: int
    points_xy: np.ndarray        #: (n, 2) its ORB keypoints
    descriptors: np.ndarray      #: (n, 32) uint8
    #: (n,) the keypoints' depths, metres (0: none); None: a camera without depth
    depths: np.ndarray | None = None

    @classmethod
    def of(cls, data: KeyFramePayload) -> LoopQuery:
        """An uploaded keyframe's features, to look for a place from."""
        return cls(data.frame_id, data.keypoints, data.descriptors, data.depths)


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
    #: the copies of other devices' keyframes the map adopted (a merged map), id → pose:
    #: held where they are by the loop's graph, with the walk's keyframes posed on them
    copies: Mapping[int, np.ndarray] = field(default_factory=dict)
    #: the managed map's copies' map points (the archived copies' are in its snapshot)
    copy_points: Mapping[int, frozenset[int]] = field(default_factory=dict)
    #: the copies a loop may close with (:func:`loop_across`; the snapshot holds those in the
    #: managed map too); empty: the walk's own keyframes alone
    across: frozenset[int] = frozenset()
    #: the tag of the walk whose keyframes :attr:`poses` are (a place's devices each walk
    #: under their own tag; 0: the place's first device, or a map of one device): its loops
    #: close among them, every other keyframe (:attr:`copies`) held as an anchor
    walk: int = 0


@dataclass(frozen=True)
class LoopResult:
    """What one job found: the loop and its pose graph's answer, or none."""

    candidate: LoopCandidate
    query: int                            #: the keyframe the loop was looked for from
    closure: LoopClosure | None
    #: the worker's time on the job, its waits for the slots left out (a busy edge's job
    #: waits seconds for them: its own work is what the edge's stats report)
    seconds: float
    #: why the job failed (an exception in the search or the graph: the edge logs it and
    #: goes on without the loop); "": it did not
    error: str = ""
    #: the job's waits for the slots' work (``pause``), seconds
    waited: float = 0.0
    #: the walk the loop was looked for in (:attr:`LoopJob.walk`)
    walk: int = 0


@dataclass
class PendingLoop:
    """A loop one keyframe found, waiting for the next keyframes to find it too."""

    candidate: LoopCandidate
    query: int
    #: the map correction it implies at its keyframe: the pose the old place gives the
    #: keyframe · the pose the walk gave it⁻¹
    correction: np.ndarray
    hits: int = 1
    misses: int = 0


class LoopConfirmation:
    """ORB-SLAM3's temporal consistency: a loop closes once ``confirmations`` later keyframes
    found the place again where its correction puts them; ``misses`` keyframes that did not
    drop it. Kept across jobs (the worker's alone: one job runs at a time)."""

    def __init__(self, confirmations: int = CONFIRMATIONS, misses: int = MISSES) -> None:
        self.confirmations = confirmations
        self.misses = misses
        self.pending: PendingLoop | None = None
        self.dropped = 0                      #: candidates never confirmed

    def judge(self, query: int, candidate: LoopCandidate, pose: np.ndarray,
              walked_m: float = 0.0) -> bool:
        """Keyframe ``query`` (at ``pose`` by the walk, ``walked_m`` from the pending
        candidate's keyframe) found ``candidate`` (or none): True when that confirms a loop,
        which closes now from this keyframe."""
        correction = None if candidate.pose is None else candidate.pose @ np.linalg.inv(pose)
        pending = self.pending
        if pending is None:
            if correction is None:
                return False
            self.pending = PendingLoop(candidate, query, correction)
            return self._confirmed()
        if correction is not None and _agree(pending.correction @ pose, correction @ pose,
                                             AGREE_M + DRIFT_RATE * walked_m):
            self.pending = PendingLoop(candidate, query, correction, pending.hits + 1,
                                       pending.misses)
            return self._confirmed()
        pending.misses += 1
        if pending.misses >= self.misses:
            self.dropped += 1
            self.pending = PendingLoop(candidate, query, correction) \
                if correction is not None else None
            return self._confirmed()
        return False

    def _confirmed(self) -> bool:
        if self.pending is not None and self.pending.hits > self.confirmations:
            self.pending = None
            return True
        return False


def _agree(a: np.ndarray, b: np.ndarray, within_m: float) -> bool:
    """Two poses of one keyframe within ``within_m`` and AGREE_DEG of each other."""
    return float(np.linalg.norm(a[:3, 3] - b[:3, 3])) <= within_m and \
        rotation_angle_deg(a[:3, :3].T @ b[:3, :3]) <= AGREE_DEG


def walk_length(poses: Mapping[int, np.ndarray], first: int, last: int) -> float:
    """Metres the walk went from keyframe ``first`` to keyframe ``last``: the steps between
    the keyframes of ``poses`` in capture (id) order."""
    ids = [k for k in sorted(poses) if first <= k <= last]
    return float(sum(np.linalg.norm(poses[b][:3, 3] - poses[a][:3, 3])
                     for a, b in itertools.pairwise(ids)))


def beyond_drift(candidate: LoopCandidate, query: int, poses: Mapping[int, np.ndarray],
                 since: int | None = None) -> str:
    """Why ``candidate``, found from keyframe ``query``, moves it farther than the walk from
    keyframe ``since`` (default: the old place) can have drifted (DRIFT_SLACK_M + DRIFT_RATE
    × its length): a look-alike place; "" when it does not."""
    if not candidate.found or candidate.pose is None or query not in poses:
        return ""
    moved = float(np.linalg.norm(candidate.pose[:3, 3] - poses[query][:3, 3]))
    walked = walk_length(poses, candidate.old if since is None else since, query)
    bound = DRIFT_SLACK_M + DRIFT_RATE * walked
    if moved <= bound:
        return ""
    return (f"{keyframe_label(candidate.old)}'s place would move keyframe {query} "
            f"{moved:.3g} m, more than the {bound:.3g} m a {walked:.3g} m walk can have "
            "drifted")


def guarded_job(job: LoopJob, min_gap: int = MIN_GAP,
                confirmation: LoopConfirmation | None = None,
                pause: Callable[[], None] = lambda: None,
                index: KeptPlaceIndex | None = None) -> LoopResult:
    """:func:`run_job`, a failure reported in the result instead of raised: a loop closer
    that fails must not take the edge's slots down with it (a kept ``index`` it was editing
    empties itself: :meth:`KeptPlaceIndex.sync`)."""
    try:
        return run_job(job, min_gap, confirmation, pause, index)
    except Exception as exc:             # reported in the result, logged by the edge
        return LoopResult(LoopCandidate(-1, None, None, 0, "the loop job failed"),
                          job.queries[0].keyframe if job.queries else -1, None, 0.0,
                          f"{type(exc).__name__}: {exc}", walk=job.walk)


def run_job(job: LoopJob, min_gap: int = MIN_GAP,
            confirmation: LoopConfirmation | None = None,
            pause: Callable[[], None] = lambda: None,
            index: KeptPlaceIndex | None = None) -> LoopResult:
    """Look for a loop from each query, oldest first; close the first one ``confirmation``
    confirms (without one: the first found). ``pause`` is called before each query and
    before the pose graph: the worker waits there for the slots' work
    (:meth:`SharedWorker.wait_for_slots`), which the result's ``seconds`` leave out
    (``waited``). The walk's own keyframes are searched under ``index`` where given (the
    loop closer's, kept from its last job: :mod:`~twinslam.slam.back_end.place_index`),
    else under an index built for this job; either answers the same."""
    start = time.perf_counter()
    waited = 0.0

    def wait() -> None:
        nonlocal waited
        began = time.perf_counter()
        pause()
        waited += time.perf_counter() - began

    candidate, query = LoopCandidate(-1, None, None, 0, "no query"), -1
    confirmed = False
    # place recognition searches only the keyframes a query may close a loop with: the
    # walk's own (its tag's: another walk's keyframes and the copies carry other tags)
    # and at least min_gap older than the newest query. A point of the recent walk or of a
    # copy that shows the same corner as an old keyframe's is as near to the query's
    # descriptor as the old one: it takes the vote (for a keyframe no loop may close with)
    # or, as the runner-up, makes Lowe's ratio refuse it — either way it hides the loop, and
    # searching those points was most of the loop closer's time
    newest = max((q.keyframe for q in job.queries), default=0)
    own = job.archive.only(lambda k: tag_of(k) == job.walk and k <= newest - min_gap, index)
    for q in sorted(job.queries, key=lambda q: q.keyframe):
        wait()
        candidate, query = detect_loop(own, q.keyframe, q.points_xy, q.descriptors,
                                       job.intrinsics, min_gap, depths=q.depths), q.keyframe
        if refused := beyond_drift(candidate, q.keyframe, job.poses):
            candidate = LoopCandidate(-1, None, None, candidate.inliers, refused)
        if not candidate.found and job.across:
            candidate = loop_across(job, q)
        if confirmation is None or q.keyframe not in job.poses:
            confirmed = candidate.found
        else:
            pending = confirmation.pending
            walked = 0.0 if pending is None else \
                walk_length(job.poses, pending.query, q.keyframe)
            confirmed = confirmation.judge(q.keyframe, candidate, job.poses[q.keyframe],
                                           walked)
        if confirmed:
            break
    closure = None
    if confirmed and candidate.measured is not None and query in job.poses:
        wait()
        # the map points of every keyframe the job knows, the copies' too: the walk's
        # covisibility counts its own keyframes' only
        points = point_id_sets({**job.map_points, **job.copy_points}, job.archive)
        closure = close_loop(job.poses, candidate.old, query, candidate.measured,
                             shared_pairs(sorted(job.poses), points), job.earlier,
                             candidate.inliers, _anchors(job, points))
    return LoopResult(candidate, query, closure, time.perf_counter() - start - waited,
                      waited=waited, walk=job.walk)


def loop_across(job: LoopJob, query: LoopQuery) -> LoopCandidate:
    """The loop ``query`` closes with a keyframe another device uploaded — one of the copies
    of ``job.across`` the merged map adopted — or why none.

    Two maps merged where their devices met are aligned there; as the devices walk on, each
    on its own keyframes, they drift apart again (on the 7-Scenes walk from its two ends,
    ~10 cm by the time they pass each other: docs/results/shared-map.md), and a rigid motion
    of one map cannot take that out. ORB-SLAM3 closes loops in a merged map between any two
    of its keyframes; here a walk that comes to a place another device mapped closes a loop
    with that device's keyframe of it, which the graph holds where its map has it
    (:func:`~twinslam.slam.back_end.pose_graph.close_loop` with the copy as an anchor): this
    walk bends towards the other device's frame where the two see one place, as its own
    loop would bend it towards its own old keyframes. Only nearby copies are searched
    (ACROSS_NEAR_M, ACROSS_NEAR_DEG), a loop that moves the query less than ACROSS_MIN_M and
    ACROSS_MIN_DEG is none, and one that moves it farther than the walk can have drifted
    from its start (DRIFT_SLACK_M + DRIFT_RATE × its length: two walks' drift apart, each
    bounded so) is a look-alike place."""
    pose = job.poses.get(query.keyframe)
    if pose is None:
        return LoopCandidate(-1, None, None, 0, "the query has no pose")
    near = {k for k in job.across
            if k in job.archive and k in job.copies and _views_near(job.copies[k], pose)}
    if not near:
        return LoopCandidate(-1, None, None, 0, "no other device's keyframe nearby")
    candidate = recognise_place(job.archive.only(near.__contains__), query.points_xy,
                                query.descriptors, job.intrinsics, depths=query.depths)
    if not candidate.found or candidate.pose is None:
        return candidate
    correction = candidate.pose @ np.linalg.inv(pose)
    moved = float(np.linalg.norm(candidate.pose[:3, 3] - pose[:3, 3]))
    if moved < ACROSS_MIN_M and rotation_angle_deg(correction[:3, :3]) < ACROSS_MIN_DEG:
        return LoopCandidate(-1, None, None, candidate.inliers,
                             f"another device's keyframe {candidate.old} agrees with the walk "
                             f"({moved * 100:.1f} cm)")
    # another device's keyframe has no place in this walk: the drift since the walk began
    if refused := beyond_drift(candidate, query.keyframe, job.poses, since=min(job.poses)):
        return LoopCandidate(-1, None, None, candidate.inliers, refused)
    return candidate


def _views_near(a: np.ndarray, b: np.ndarray) -> bool:
    """Two cameras (camera-to-map) within ACROSS_NEAR_M of each other, their optical axes
    within ACROSS_NEAR_DEG."""
    if float(np.linalg.norm(a[:3, 3] - b[:3, 3])) > ACROSS_NEAR_M:
        return False
    cos = float(np.clip(a[:3, 2] @ b[:3, 2], -1.0, 1.0))
    return float(np.degrees(np.arccos(cos))) <= ACROSS_NEAR_DEG


def _anchors(job: LoopJob, points: Mapping[int, np.ndarray]) -> Anchors | None:
    """The job's copies as the anchors of its graph (none: a map that adopted none;
    ``points``: every keyframe's map points)."""
    if not job.copies:
        return None
    return copy_anchors(points, job.copies, job.copies, job.walk)


_T = TypeVar("_T")


#: how much lower than the slots' the loop worker's priority is by default (Linux nice steps;
#: 0: the same)
WORKER_NICENESS = 0
#: the most of a core the loop worker takes by default (1: all it can get)
WORKER_SHARE = 1.0
#: whether the loop worker waits for the slots' work by default (before each query)
WORKER_YIELDS = True
#: the longest the worker waits for the slots' work before a query, when it yields to it
YIELD_AT_MOST_S = 0.5
#: the longest work queued behind the loops' (a place look) waits while loop work keeps
#: coming: past it, it goes next — on a host the loops keep busy, devices still merge. On one
#: full core (twelve devices, the walk that comes back) 5 s let the looks take back most of
#: the loops the loops-first order saved (33-34 closed of 60 against 36-44 unbounded,
#: 29-31 in the order the work came); 15 s closed 37-44
AFTER_LOOPS_AT_MOST_S = 15.0


@dataclass(frozen=True)
class _Queued:
    """A piece of work waiting for the worker, and when it was queued (monotonic)."""

    future: Future[Any]
    fn: Callable[..., Any]
    args: tuple[Any, ...]
    queued_at: float


def _cancelled_ahead(queue: deque[_Queued]) -> list[_Queued]:
    """The cancelled work at the head of ``queue``, taken off it."""
    taken = []
    while queue and queue[0].future.cancelled():
        taken.append(queue.popleft())
    return taken


class SharedWorker:
    """The one thread the process's background loop closers queue their work on, started
    with the first work it gets (and again after :meth:`stop`), ``niceness`` steps below the
    priority of the thread that starts it, and taking at most ``share`` of a core: after each
    piece of work it rests until its CPU time is that share of the time since it began."""

    def __init__(self, niceness: int = WORKER_NICENESS, share: float = WORKER_SHARE) -> None:
        self._lock = threading.Lock()
        self._executor: ThreadPoolExecutor | None = None
        #: the work not started yet, each kind in the order it came: the loops' and the
        #: work that goes after them (:meth:`submit`)
        self._loops: deque[_Queued] = deque()
        self._after_loops: deque[_Queued] = deque()
        #: the longest work queued ``after_loops`` waits while loop work keeps coming
        self.after_loops_at_most_s = AFTER_LOOPS_AT_MOST_S
        #: pieces of after-loops work that went before waiting loop work so far, having
        #: waited past that bound: a worker the loops keep busy (the edge's /diagnostics)
        self.overdue = 0
        self.niceness = niceness
        self.share = share
        #: the worker thread's nice value once it started (None: not started, or not Linux)
        self.nice: int | None = None
        self._rest_until = 0.0                 #: monotonic time the next work may start
        self.rested_s = 0.0                    #: seconds it rested so far (its share's cost)
        #: wait while the slots' work runs (:meth:`yield_to_slots`)
        self.yields = WORKER_YIELDS
        self._slot_work = 0                    #: slot callbacks running now
        #: guards the count; notified when it falls to none
        self._slots_done = threading.Condition()
        self._marks = threading.local()        #: each thread's slot-work marks (``depth``)
        self.yielded_s = 0.0                   #: seconds it waited for the slots so far

    def lower_priority(self, niceness: int) -> None:
        """Run the worker ``niceness`` steps (0-19) below the slots' priority from its next
        start (the edge node's ``loop_worker_niceness``); 0: at the same priority."""
        check_niceness(niceness)
        self.niceness = niceness

    def limit_share(self, share: float) -> None:
        """Let the worker take at most ``share`` (0-1] of a core from its next piece of work
        on (the edge node's ``loop_worker_share``); 1: no limit."""
        if not 0 < share <= 1:
            raise ValueError(f"a share of a core is above 0 and at most 1, not {share:g}")
        self.share = share

    def yield_to_slots(self, yields: bool) -> None:
        """Let the worker wait, before each loop query, while the slots' work runs (the edge
        node's ``loop_worker_yields``): within one process the worker and the slot thread
        share one interpreter, which a nice value does not reach — the slots' callbacks
        then run alone, the loops in the gaps between them (each wait at most
        YIELD_AT_MOST_S: the loops are delayed, never starved)."""
        self.yields = yields

    @contextmanager
    def slot_work(self) -> Iterator[None]:
        """Mark the slots' work running (the edge's callbacks), for :meth:`wait_for_slots`."""
        self._mark(1)
        self._marks.depth = getattr(self._marks, "depth", 0) + 1
        try:
            yield
        finally:
            self._marks.depth -= 1
            self._mark(-1)

    @contextmanager
    def outside_slot_work(self) -> Iterator[None]:
        """The calling thread's slot-work marks lifted while it waits for the worker (a merge
        dropping the running loop job): else the worker, waiting for the slots, would wait
        for the very callback that waits for it."""
        depth = getattr(self._marks, "depth", 0)
        self._mark(-depth)
        self._marks.depth = 0
        try:
            yield
        finally:
            self._marks.depth = depth
            self._mark(depth)

    @property
    def slots_idle(self) -> bool:
        """No slot work runs now."""
        return not self._slot_work

    def _mark(self, change: int) -> None:
        with self._slots_done:
            self._slot_work += change
            if not self._slot_work:
                self._slots_done.notify_all()

    def wait_for_slots(self) -> None:
        """With :attr:`yields`, wait until no slot work runs (YIELD_AT_MOST_S at most)."""
        if not self.yields or self.slots_idle:
            return
        began = time.monotonic()
        with self._slots_done:
            self._slots_done.wait_for(lambda: self.slots_idle, YIELD_AT_MOST_S)
        self.yielded_s += time.monotonic() - began

    def submit(self, fn: Callable[..., _T], *args: object,
               after_loops: bool = False) -> Future[_T]:
        """``fn(*args)`` queued on the worker: after the work queued before it of its kind,
        and with ``after_loops`` (a place look, the keyframe database's filing) after every
        loop job and loop correction queued before it starts — those go first, in the order
        they came — unless it has waited :attr:`after_loops_at_most_s` already. Its future may
        be cancelled until it starts."""
        future: Future[_T] = Future()
        with self._lock:
            if self._executor is None:
                self.nice = None
                self._executor = ThreadPoolExecutor(
                    1, thread_name_prefix="loop-closer",
                    initializer=_lowered, initargs=(self, os.getpriority(os.PRIO_PROCESS, 0)
                                                    if PER_THREAD_NICE else 0))
            queue = self._after_loops if after_loops else self._loops
            queue.append(_Queued(future, fn, args, time.monotonic()))
            # one turn a piece of work: each turn runs whichever goes first then
            self._executor.submit(self._turn)
        return future

    def waiting(self) -> tuple[int, int]:
        """The pieces of work queued, not started and not cancelled now: (loop work, work
        after the loops)."""
        with self._lock:
            return (sum(not q.future.cancelled() for q in self._loops),
                    sum(not q.future.cancelled() for q in self._after_loops))

    def _turn(self) -> None:
        """Run the work that goes first now (skipped if it was cancelled): the oldest loop
        work, unless none waits or the oldest work queued after the loops has waited past its
        bound."""
        with self._lock:
            # work cancelled while it waited is dropped first: it neither goes before the
            # loops nor counts as overdue (each turn still ends one piece, run or dropped)
            dropped = [*_cancelled_ahead(self._loops), *_cancelled_ahead(self._after_loops)]
            overdue = bool(self._after_loops) and (
                time.monotonic() - self._after_loops[0].queued_at > self.after_loops_at_most_s)
            if self._loops and not overdue:
                work: _Queued | None = self._loops.popleft()
            elif self._after_loops:
                self.overdue += bool(self._loops)      # went before loop work that waits
                work = self._after_loops.popleft()
            else:
                work = None                            # its piece was dropped by another turn
        for cancelled in dropped:
            cancelled.future.set_running_or_notify_cancel()    # tells their waiters
        if work is None or not work.future.set_running_or_notify_cancel():
            return
        future = work.future
        try:
            result = self._paced(work.fn, *work.args)
        except BaseException as exc:             # as the executor's own work items do
            future.set_exception(exc)
        else:
            future.set_result(result)

    def _paced(self, fn: Callable[..., _T], *args: object) -> _T:
        """``fn(*args)`` on the worker, after the rest the work before it earned: a piece
        that used c seconds of CPU is followed by c (1 − share) / share seconds idle."""
        rest = self._rest_until - time.monotonic()
        if rest > 0:
            time.sleep(rest)
            self.rested_s += rest
        used = time.thread_time()
        try:
            return fn(*args)
        finally:
            if self.share < 1:
                used = time.thread_time() - used
                self._rest_until = time.monotonic() + used * (1 - self.share) / self.share

    def stop(self) -> None:
        """End the thread once its queue is done (a process that stops)."""
        with self._lock:
            executor, self._executor = self._executor, None
        if executor is not None:
            executor.shutdown(wait=True)


def _lowered(worker: SharedWorker, starter_nice: int) -> None:
    """The worker thread's first step: its own nice value ``worker.niceness`` above the
    thread that started it (a lower priority only: no privilege needed), and its name
    ("loop-closer_0") where ``top -H`` and ``ps -L`` show it."""
    name_this_thread()
    nice = lower_this_thread(worker.niceness, above=starter_nice)
    if nice is not None:
        worker.nice = nice


#: the worker every background loop closer of this process shares
SHARED_WORKER = SharedWorker()


class LoopCloser:
    """One loop job at a time, on the process's loop-closing worker (or in the caller)."""

    def __init__(self, background: bool = True, min_gap: int = MIN_GAP,
                 cooldown: int = COOLDOWN, confirmations: int = CONFIRMATIONS) -> None:
        self.background = background
        self.min_gap = min_gap
        self.cooldown = cooldown
        #: the loops found and waiting for later keyframes, a confirmation a walk (the
        #: worker's: one job at a time)
        self._confirmations: dict[int, LoopConfirmation] = {}
        self._confirmations_needed = confirmations
        #: its work queued or running on the shared worker, oldest first (close waits for it)
        self._queued: deque[Future[Any]] = deque()
        self._running: Future[LoopResult] | None = None
        self._done: LoopResult | None = None
        #: walk → its keyframe ids up to this look for no loop (a closed loop's cooldown)
        self._quiet_until: dict[int, int] = {}
        #: why work handed to :meth:`after` failed, until :meth:`failures` takes them (the
        #: worker appends, the slot takes: under the lock, none is lost between the two)
        self._failed: list[str] = []
        self._failed_lock = threading.Lock()
        #: the worker's seconds on each of the latest JOB_TIMES_KEPT jobs taken, oldest first
        self.job_seconds: deque[float] = deque(maxlen=JOB_TIMES_KEPT)
        #: walk → the place index of its keyframes, kept from one job to the next: an edge
        #: that has run for minutes built one over hundreds of archived keyframes for every
        #: job (:mod:`~twinslam.slam.back_end.place_index`)
        self._place_indexes: dict[int, KeptPlaceIndex] = {}

    @property
    def confirmation(self) -> LoopConfirmation:
        """The loop waiting for confirmation on the first walk (a map of one device's)."""
        return self.confirmation_of(0)

    def confirmation_of(self, walk: int) -> LoopConfirmation:
        """Walk ``walk``'s loop waiting for later keyframes of it: one walk's keyframes
        confirm its own loops, never another's."""
        if walk not in self._confirmations:
            self._confirmations[walk] = LoopConfirmation(self._confirmations_needed)
        return self._confirmations[walk]

    def place_index(self, walk: int = 0) -> KeptPlaceIndex:
        """The kept place index of walk ``walk``'s keyframes."""
        return self._place_indexes.setdefault(walk, KeptPlaceIndex())

    @property
    def busy(self) -> bool:
        return self._running is not None and not self._running.done()

    def wanted(self, keyframes: Sequence[int]) -> list[int]:
        """Of ``keyframes``, those that may look for a loop now (not in a closed loop's
        cooldown)."""
        return [k for k in keyframes if k > self._quiet_until.get(tag_of(k), -1)]

    def submit(self, job: LoopJob) -> bool:
        """Start ``job``; False (nothing started) while one runs or waits to be taken."""
        if self._running is not None or self._done is not None or not job.queries:
            return False
        confirmation, index = self.confirmation_of(job.walk), self.place_index(job.walk)
        if not self.background:
            self._done = guarded_job(job, self.min_gap, confirmation, index=index)
            return True
        self._running = self._queue(guarded_job, job, self.min_gap, confirmation,
                                    SHARED_WORKER.wait_for_slots, index)
        return True

    def take(self, wait_s: float = 0.0) -> LoopResult | None:
        """The finished job's result (once), waiting up to ``wait_s`` for a running one; None
        while it runs or when none was started."""
        if self._running is not None:
            if wait_s <= 0:
                self._done = self._running.result() if self._running.done() else None
            else:
                try:        # the caller blocks on the worker: its slot-work marks lifted
                    with SHARED_WORKER.outside_slot_work():
                        self._done = self._running.result(timeout=wait_s)
                except TimeoutError:
                    return None
            if self._done is None:
                return None
            self._running = None
        done, self._done = self._done, None
        if done is not None:
            self.job_seconds.append(done.seconds)
        if done is not None and done.closure is not None:
            self._quiet_until[done.walk] = done.query + self.cooldown
        return done

    def discard(self) -> None:
        """Drop the job running or waiting to be taken (waiting for a running one to end) and
        the loop waiting for confirmation: their poses are of a frame the map has left (a
        map merge moved it, :meth:`MapBackEnd.align`)."""
        if self._running is not None:
            with SHARED_WORKER.outside_slot_work():
                self._running.result()
        self._running = self._done = None
        for confirmation in self._confirmations.values():
            confirmation.pending = None

    def after(self, work: Callable[[], object], what: str) -> None:
        """Run ``work`` (``what`` it does, for its failure's message) on the worker after what
        it has queued (in the caller without one): the archive's pose file after a correction,
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
        self._queue(guarded)

    def failures(self) -> list[str]:
        """What the work handed to :meth:`after` failed on since the last call (once each)."""
        with self._failed_lock:
            failed, self._failed = self._failed, []
        return failed

    def _queue(self, fn: Callable[..., _T], *args: object) -> Future[_T]:
        """``fn(*args)`` queued on the shared worker, after everything queued before it (its
        own earlier work included: a correction's files follow the job that made them)."""
        while self._queued and self._queued[0].done():
            self._queued.popleft()
        future = SHARED_WORKER.submit(fn, *args)
        self._queued.append(future)
        return future

    def close(self) -> None:
        """Wait for its work queued on the shared worker: a running job finishes, one not
        started yet is dropped (its answer would go to a map that is closing), the archive's
        files of a correction (:meth:`after`) are written."""
        if self._running is not None and self._running.cancel():    # False once it runs
            self._running = None
        with SHARED_WORKER.outside_slot_work():
            wait(list(self._queued))
        self._queued.clear()
