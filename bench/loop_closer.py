"""How long the edge's loop closer takes, and what it costs the slot beside it: an archive of
real keyframes of an RGB-D walk (ORB features, points from depth at the true poses), frames of
the same walk looking for a loop in it, the pose graph over archive and map, and the
corrections applied to a managed map and the archive.

    python -m bench.loop_closer [SEQUENCE] [--archive 500] [--queries 20] [--map 45]
                                [--exact-below 20000] [--words-from OTHER_SEQUENCE]

Prints the medians and 95th percentiles of: the archive's snapshot (on the slot's path), place
recognition with the geometric check — searching the points under the archive's visual words
(:mod:`twinslam.slam.back_end.place_words`) and, side by side on the same queries, every point
exactly, with how often the two find the same place and pose —, the pose graph, the whole job
(the worker thread's time), the corrections applied to the map and the archive (on the slot's
path) and the corrected archive written to disk (the worker: its pose file, since 2026-12-04;
every moved keyframe's file before); then a slot's work on the main thread
(the map's keyframes archived, as at an eviction) alone and while the worker closes loops back
to back: the worker's share of the interpreter (the GIL) shows as the slot's work taking
longer.

``--words-from`` searches the archive under visual words learned from another place's
archive (as many keyframes of another sequence), as an edge process whose devices share one
vocabulary does (:meth:`~twinslam.slam.back_end.place_words.PlaceWords.share`): the same
place and pose as the exact search tells whether the words of one place serve another.
"""

from __future__ import annotations

import argparse
import platform
import statistics
import sys
import tempfile
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from bench.paths import SEVEN_SCENES
from twinslam.cli.console import HelpFormatter
from twinslam.rotations import rotation_angle_deg
from twinslam.sequences.opening import open_sequence
from twinslam.slam.back_end.keyframe_archive import (
    ArchivedKeyFrame,
    KeyFrameArchive,
    point_id_sets,
    restore_into,
)
from twinslam.slam.back_end.keyframe_map import KeyFrameMap, shared_pairs
from twinslam.slam.back_end.loop_closing import (
    CONFIRMATIONS,
    LoopConfirmation,
    LoopJob,
    LoopQuery,
    run_job,
)
from twinslam.slam.back_end.loop_correction import correct_map
from twinslam.slam.back_end.loop_detection import LoopCandidate, detect_loop
from twinslam.slam.back_end.place_index import KeptPlaceIndex
from twinslam.slam.back_end.place_words import EXACT_BELOW, PlaceWords
from twinslam.slam.back_end.pose_graph import close_loop
from twinslam.slam.front_end.orb_extractor import OrbExtractor
from twinslam.slam.front_end.tracking import depth_at
from twinslam.slam.projection_matching import back_project

SEQUENCE = SEVEN_SCENES
#: query keyframe ids: the walk's frames seen again this much later
LATER = 10_000


@contextmanager
def _timed(runs: list[float]) -> Iterator[None]:
    """Append the milliseconds the block took to ``runs``."""
    start = time.perf_counter()
    yield
    runs.append((time.perf_counter() - start) * 1e3)


def _line(name: str, runs: list[float]) -> str:
    p95 = float(np.percentile(runs, 95)) if runs else float("nan")
    median = statistics.median(runs) if runs else float("nan")
    return f"  {name:<44} {median:8.1f} ms median, {p95:8.1f} ms p95 ({len(runs)} runs)"


def build(sequence: str, keyframes: int, orb: OrbExtractor, exact_below: int = EXACT_BELOW,
          words_only: bool = False) -> tuple[KeyFrameArchive, object]:
    """An archive of ``keyframes`` keyframes spread over the walk, placed at the true poses,
    searched exactly below ``exact_below`` points; ``words_only``: an archive only its
    descriptors are read from (to learn its words), a frame without a true pose placed at the
    origin."""
    reader = open_sequence(sequence)
    # a sequence shorter than the archive gives each of its frames once
    frames = np.unique(np.linspace(0, len(reader) - 1, keyframes).round().astype(int))
    archive = KeyFrameArchive(keyframes, words=PlaceWords(exact_below))
    first = 1
    for kf in frames.tolist():
        frame = reader.read(kf)                                 # type: ignore[attr-defined]
        pose = frame.pose if frame.pose is not None or not words_only else np.eye(4)
        if pose is None:
            raise SystemExit(f"bench.loop_closer: frame {kf} of {sequence} has no true pose")
        feats = orb.extract(frame.color)
        z = depth_at(feats.points, frame.depth, (0.2, 8.0))
        keep = z > 0
        n = int(keep.sum())
        archive.add(ArchivedKeyFrame(
            kf, pose.copy(), np.arange(first, first + n),
            back_project(feats.points[keep], z[keep], reader.intrinsics, pose),
            feats.descriptors[keep], np.column_stack([feats.points[keep], z[keep]]), 0))
        first += n
    return archive, reader


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=HelpFormatter)
    parser.add_argument("sequence", nargs="?", default=str(SEQUENCE),
                        help="an RGB-D sequence with poses (default: the bundled 7-Scenes "
                        "sample)")
    parser.add_argument("--archive", type=int, default=500,
                        help="archived keyframes (the edge's archive_keyframes default)")
    parser.add_argument("--queries", type=int, default=20,
                        help="frames of the walk that look for a loop")
    parser.add_argument("--map", type=int, default=45,
                        help="keyframes of the managed map the corrections move (V_max)")
    parser.add_argument("--jobs", type=int, default=12,
                        help="loop jobs on an archive that changes between them, each run "
                        "with the place index built for it and with the loop closer's kept "
                        "(at most (archive + 2) // 4: each job archives a keyframe and "
                        "restores an older one)")
    parser.add_argument("--exact-below", type=int, default=EXACT_BELOW,
                        help="points under which the archive is searched exactly, not under "
                        "its visual words (the edge's setting)")
    parser.add_argument("--words-from", metavar="SEQUENCE", default="",
                        help="search under the visual words learned from an archive of as "
                        "many keyframes of this other sequence (another place), not the "
                        "archive's own")
    args = parser.parse_args()
    if not 1 <= args.jobs <= (args.archive + 2) // 4:
        # job n archives keyframe archive - jobs + n and restores keyframe 3n, which must
        # still be archived then
        parser.error(f"--jobs: 1 to {(args.archive + 2) // 4} for an archive of "
                     f"{args.archive} keyframes, not {args.jobs}")
    print(f"loop closer: {platform.processor() or platform.machine()}, "
          f"{time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}; {args.archive} archived "
          f"keyframes of {args.sequence}, {args.queries} queries, a map of {args.map}")
    orb = OrbExtractor()
    archive, reader = build(args.sequence, args.archive, orb, args.exact_below)
    k = reader.intrinsics                                       # type: ignore[attr-defined]
    kept = list(archive)
    exact = KeyFrameArchive(args.archive, words=PlaceWords(exact_below=sys.maxsize))
    for kf in kept:
        exact.add(kf, write=False)
    n_points = _points_in(kept)
    foreign = _foreign_words(args.words_from, args.archive, orb, args.exact_below) \
        if args.words_from else None
    if foreign is not None:
        archive.words.share(foreign)
    start = time.perf_counter()
    archive.snapshot().recognise(kept[0].descriptors)      # learns the words (once an archive)
    vocabulary = archive.words.source().vocabulary
    print(f"  {n_points} points; the archive's vocabulary: "
          f"{'none (searched exactly)' if vocabulary is None else f'{vocabulary.words} words'}"
          f", {'learned and ' if foreign is None else ''}the points filed in "
          f"{(time.perf_counter() - start) * 1e3:.0f} ms")
    if foreign is not None:
        print(f"  the words learned from {args.words_from}"
              + (" (this archive outgrew them eightfold: learned again from its own points)"
                 if foreign.learned > 1 else ""))
    managed = KeyFrameMap()
    managed.next_point_id = 1 + sum(len(kf.point_ids) for kf in kept)
    for kf in kept[-args.map:]:
        restore_into(managed, kf)
    poses = {kf.id: kf.pose for kf in kept}
    points = {kf.id: frozenset(kf.point_ids.tolist()) for kf in kept}
    times: dict[str, list[float]] = {name: [] for name in (
        "snapshot", "detect", "exact", "graph", "job", "map", "archive", "files")}
    found = found_exact = same = 0
    inliers: list[tuple[int, int]] = []      #: (under the words, exact) where both found it
    queries: list[LoopQuery] = []            #: each frame's, for the jobs below
    n_frames = len(reader)                                      # type: ignore[arg-type]
    for q, index in enumerate(np.linspace(1, n_frames - 2, args.queries).round().astype(int)):
        frame = reader.read(int(index))                         # type: ignore[attr-defined]
        feats = orb.extract(frame.color)
        query = LATER + int(index)
        drifted = frame.pose.copy()
        drifted[:3, 3] += (0.05, 0.0, 0.02)                     # the walk's drift at the loop
        with _timed(times["snapshot"]):
            snapshot = archive.snapshot()
        with _timed(times["detect"]):
            loop = detect_loop(snapshot, query, feats.points, feats.descriptors, k)
        with _timed(times["exact"]):
            beside = detect_loop(exact.snapshot(), query, feats.points, feats.descriptors, k)
        found_exact += beside.found
        same += _same_place(loop, beside)
        if loop.found and beside.found:
            inliers.append((loop.inliers, beside.inliers))
        queries.append(LoopQuery(query, feats.points, feats.descriptors))
        job = LoopJob((queries[-1],), snapshot,
                      {**poses, query: drifted}, k, {**points, query: frozenset()})
        if not loop.found or loop.measured is None:
            continue
        found += 1
        shared = shared_pairs(sorted(job.poses), point_id_sets(job.map_points, job.archive))
        with _timed(times["graph"]):
            closure = close_loop(job.poses, loop.old, query, loop.measured, shared)
        with _timed(times["job"]):
            run_job(job)
        with _timed(times["map"]):
            correct_map(managed, closure.corrections)
        if q < 5:                                 # written to disk: a few rounds are enough
            with tempfile.TemporaryDirectory() as tmp:
                on_disk = KeyFrameArchive(args.archive, Path(tmp))
                for kf in kept:
                    on_disk.add(kf)
                with _timed(times["archive"]):
                    on_disk.correct(closure.corrections, write=False)
                with _timed(times["files"]):
                    on_disk.save_poses()
    print(f"  loops found: {found} of {args.queries} queries; searching every point exactly "
          f"{found_exact}; the same place and pose (within 1 cm, 0.5°) {same}; PnP inliers "
          f"{_inliers(inliers)}")
    labels = {"snapshot": "archive snapshot (slot's path)",
              "detect": "place recognition + PnP (worker)",
              "exact": "the same, every point searched exactly",
              "graph": f"pose graph over {args.archive + 1} keyframes (worker)",
              "job": "the whole job (worker)",
              "map": f"corrections on a map of {args.map} (slot's path)",
              "archive": "corrections on the archive (slot's path)",
              "files": "the corrected archive on disk (worker)"}
    for name, label in labels.items():
        print(_line(label, times[name]))
    built, kept_index, agreed, index = changing_archive_jobs(kept, archive.words, queries, k,
                                                             args.jobs)
    print(f"  jobs on an archive that changes between them (one keyframe archived, one "
          f"restored), alternated; {agreed} of {len(built)} found the same place on as many "
          f"inliers; the kept index {index.nbytes / 1e6:.0f} MB, the archive's keyframes "
          f"{archive.nbytes / 1e6:.0f} MB:")
    print(_line("a job, its place index built for it", built))
    print(_line("a job, the loop closer's index kept", kept_index))
    print(contention(archive, managed, k, reader, orb))


def _foreign_words(sequence: str, keyframes: int, orb: OrbExtractor, exact_below: int
                   ) -> PlaceWords:
    """The visual words of an archive of ``keyframes`` keyframes of another ``sequence``
    (another place), learned now; exits with a message where that archive holds too few
    points to need words."""
    other, _ = build(sequence, keyframes, orb, exact_below, words_only=True)
    kept = list(other)
    other.snapshot().recognise(kept[0].descriptors)        # learns the words (once an archive)
    if other.words.vocabulary is None:
        raise SystemExit(f"bench.loop_closer: {sequence} gave {len(kept)} keyframes of "
                         f"{_points_in(kept)} points, fewer than the {exact_below} that learn "
                         "words (--exact-below)")
    return other.words


def changing_archive_jobs(kept: list[ArchivedKeyFrame], words: PlaceWords,
                          queries: list[LoopQuery], k: np.ndarray, jobs: int
                          ) -> tuple[list[float], list[float], int, KeptPlaceIndex]:
    """``jobs`` loop jobs, each on an archive that changed since the last as an edge's does
    between two slots — the next of ``kept`` archived, an old one restored — run twice,
    alternately: with the place index built for the job, and with the loop closer's index
    kept from its last job (:mod:`~twinslam.slam.back_end.place_index`). Each job detects
    only (a loop waits for its confirmations), as most slots' jobs do. Returns the two runs'
    milliseconds, how many jobs found the same place on as many inliers both ways, and the
    kept index."""
    live = KeyFrameArchive(len(kept), words=words)
    head = len(kept) - jobs
    for kf in kept[:head]:
        live.add(kf, write=False)
    index = KeptPlaceIndex()
    poses = {kf.id: kf.pose for kf in kept} | {q.keyframe: np.eye(4) for q in queries}
    points = {q.keyframe: frozenset[int]() for q in queries}

    def job(query: LoopQuery) -> LoopJob:
        return LoopJob((query,), live.snapshot(), poses, k, points)

    run_job(job(queries[0]), index=index)        # the index's first fill: once an edge's life
    built: list[float] = []
    with_index: list[float] = []
    agreed = 0
    for n in range(jobs):
        live.add(kept[head + n], write=False)
        live.take(kept[3 * n].id)
        this = job(queries[n % len(queries)])
        with _timed(built):
            fresh = run_job(this, confirmation=LoopConfirmation(CONFIRMATIONS))
        with _timed(with_index):
            kept_ = run_job(this, confirmation=LoopConfirmation(CONFIRMATIONS), index=index)
        agreed += (fresh.candidate.old, fresh.candidate.inliers) == \
            (kept_.candidate.old, kept_.candidate.inliers)
    return built, with_index, agreed, index


def _points_in(keyframes: list[ArchivedKeyFrame]) -> int:
    """The map points the archived ``keyframes`` observe, each once."""
    return len(np.unique(np.concatenate([kf.point_ids for kf in keyframes])))


def _inliers(pairs: list[tuple[int, int]]) -> str:
    """The PnP inliers of the places both searches found: the medians under the words and
    exactly, and the words' share of the exact search's (the points the words' probes miss)."""
    if not pairs:
        return "(no place both found)"
    words, exact = (np.array(side, dtype=float) for side in zip(*pairs, strict=True))
    return (f"{statistics.median(words):.0f} median under the words against "
            f"{statistics.median(exact):.0f} exactly ({words.sum() / exact.sum():.1%})")


def _same_place(a: LoopCandidate, b: LoopCandidate) -> bool:
    """Two searches found the same old keyframe and put the query within 1 cm and 0.5°."""
    if a.pose is None or b.pose is None or a.old != b.old:
        return False
    return bool(np.linalg.norm(a.pose[:3, 3] - b.pose[:3, 3]) <= 0.01
                and rotation_angle_deg(a.pose[:3, :3].T @ b.pose[:3, :3]) <= 0.5)


def contention(archive: KeyFrameArchive, managed: KeyFrameMap, k: np.ndarray, reader: object,
               orb: OrbExtractor, rounds: int = 20) -> str:
    """A slot's work on the main thread (every map keyframe archived, as evictions do) alone,
    then while the worker runs loop jobs back to back."""
    def slot_work() -> None:
        for kf in list(managed.keyframes):
            ArchivedKeyFrame.of(managed, kf, 0)
    frame = reader.read(3)                                      # type: ignore[attr-defined]
    feats = orb.extract(frame.color)
    job = LoopJob((LoopQuery(LATER + 3, feats.points, feats.descriptors),), archive.snapshot(),
                  {**{kf.id: kf.pose for kf in archive}, LATER + 3: frame.pose}, k, {})
    alone: list[float] = []
    for _ in range(rounds):
        with _timed(alone):
            slot_work()
    busy: list[float] = []
    stop = threading.Event()

    def worker() -> None:
        while not stop.is_set():
            run_job(job)
    thread = threading.Thread(target=worker, daemon=True)
    thread.start()
    time.sleep(0.2)
    for _ in range(rounds):
        with _timed(busy):
            slot_work()
    stop.set()
    thread.join(timeout=60)
    return "\n".join([_line("a slot's work alone (main thread)", alone),
                      _line("the same beside the loop closer", busy)])


if __name__ == "__main__":
    main()
