"""How well the device tracked, as a user of the live system measures it.

* **ATE** — RMSE of the device's positions against ground truth after one SE(3) alignment
  (evo's APE, translation part): the drift and jumps of the whole run.
* **RPE** — RMSE of the translation error of relative motions over ``delta`` frames (evo's
  RPE): local consistency, blind to one-off offsets, sensitive to jumps.
* **Tracking events**, from the device's per-frame flags (``FrameSummary.tracked`` /
  ``relocalised``): a *failure* is a tracked frame followed by an untracked one; a
  *relocalisation* is a frame tracked again by relocalisation against the local map — the
  edge's last map and the device's few own recent points; *time to recover* runs from the
  first untracked frame to the next tracked one (a loss never recovered counts up to the last
  frame and is reported apart).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from twinslam.rotations import rotation_angle_deg
from twinslam.slam.back_end.depth_alignment import rigid_fit


@dataclass(frozen=True)
class FrameFlags:
    stamp: float
    tracked: bool
    relocalised: bool


@dataclass
class TrackingEvents:
    frames: int = 0
    untracked: int = 0
    failures: int = 0
    relocalisations: int = 0
    unrecovered: int = 0                  #: losses still lost at the last frame
    recover_s: list[float] = field(default_factory=list)   #: per recovered loss
    #: every loss's seconds untracked: a recovered one until tracking again, one still lost
    #: at the end until the last frame (what the run saw of it)
    loss_s: list[float] = field(default_factory=list)

    @property
    def mean_recover_s(self) -> float:
        """Mean seconds from a loss to tracking again (NaN when nothing was lost)."""
        return float(np.mean(self.recover_s)) if self.recover_s else math.nan

    @property
    def failed_share(self) -> float:
        """The share of frames not tracked (NaN without frames)."""
        return self.untracked / self.frames if self.frames else math.nan

    @property
    def loss_p95_s(self) -> float:
        """The 95th percentile of the losses' durations, seconds (0: nothing was lost): how
        long a user is left without a pose, nearly at worst."""
        return float(np.percentile(self.loss_s, 95)) if self.loss_s else 0.0

    @property
    def longest_loss_s(self) -> float:
        """The longest loss, seconds (0: nothing was lost)."""
        return max(self.loss_s, default=0.0)


def tracking_events(frames: Iterable[FrameFlags]) -> TrackingEvents:
    """Count failures, relocalisations, recovery times and losses over frames in stamp
    order."""
    out = TrackingEvents()
    lost_since: float | None = None
    previous_tracked, last = True, 0.0
    for f in sorted(frames, key=lambda f: f.stamp):
        out.frames += 1
        out.untracked += not f.tracked
        out.relocalisations += f.tracked and f.relocalised
        if not f.tracked and previous_tracked:
            out.failures += 1
            lost_since = f.stamp
        elif f.tracked and lost_since is not None:
            out.recover_s.append(f.stamp - lost_since)
            out.loss_s.append(f.stamp - lost_since)
            lost_since = None
        previous_tracked = f.tracked
        last = f.stamp
    out.unrecovered = int(lost_since is not None)
    if lost_since is not None:
        out.loss_s.append(last - lost_since)
    return out


def _aligned_paths(poses: Mapping[int, np.ndarray], truth: Mapping[int, np.ndarray]
                   ) -> tuple[object, object] | None:
    from evo.core.trajectory import PosePath3D

    common = sorted(set(poses) & set(truth))
    if len(common) < 3:
        return None
    est = PosePath3D(poses_se3=[poses[s] for s in common])
    ref = PosePath3D(poses_se3=[truth[s] for s in common])
    est.align(ref, correct_scale=False)
    return ref, est


def truth_in_map(poses: Mapping[int, np.ndarray], truth: Mapping[int, np.ndarray]
                 ) -> dict[int, np.ndarray]:
    """The ground truth moved into the device's map frame by the inverse of the SE(3)
    alignment ATE uses (so a picture shows it beside the map); empty with fewer than 3 common
    stamps."""
    from evo.core import geometry

    common = sorted(set(poses) & set(truth))
    if len(common) < 3:
        return {}
    est = np.array([poses[s][:3, 3] for s in common]).T
    ref = np.array([truth[s][:3, 3] for s in common]).T
    rotation, translation, _ = geometry.umeyama_alignment(est, ref, False)
    world_from_map = np.eye(4)
    world_from_map[:3, :3], world_from_map[:3, 3] = rotation, translation
    map_from_world = np.linalg.inv(world_from_map)
    return {s: map_from_world @ pose for s, pose in truth.items()}


def absolute_trajectory_error(poses: Mapping[int, np.ndarray],
                              truth: Mapping[int, np.ndarray]) -> float:
    """ATE (m) over the stamps both hold; NaN with fewer than 3 common stamps."""
    from evo.core import metrics

    paths = _aligned_paths(poses, truth)
    if paths is None:
        return math.nan
    ape = metrics.APE(metrics.PoseRelation.translation_part)
    ape.process_data(paths)
    return float(ape.get_statistic(metrics.StatisticsType.rmse))


def relative_pose_error(poses: Mapping[int, np.ndarray], truth: Mapping[int, np.ndarray],
                        delta: int = 30) -> float:
    """RPE (m): translation RMSE of motions over ``delta`` frames (30: one second at 30 Hz),
    every pair; NaN when the run is shorter than ``delta`` + 1 common stamps."""
    from evo.core import metrics

    paths = _aligned_paths(poses, truth)
    if paths is None or len(paths[0].poses_se3) <= delta:   # type: ignore[attr-defined]
        return math.nan
    rpe = metrics.RPE(metrics.PoseRelation.translation_part, delta=delta,
                      delta_unit=metrics.Unit.frames, all_pairs=True)
    rpe.process_data(paths)
    return float(rpe.get_statistic(metrics.StatisticsType.rmse))


#: a published pose whose aligned error is this much larger than the one before it is a
#: *jump*: a wrong relocalisation, a diverged solve, a map swap gone astray — what a user sees
#: as the virtual content leaping across the room
JUMP_M = 0.3


def translation_errors(poses: Mapping[int, np.ndarray], truth: Mapping[int, np.ndarray]
                       ) -> dict[int, float]:
    """Per stamp both hold: the distance (m) between the device's position and the true one
    after the SE(3) alignment ATE uses (ATE is their RMSE); empty with fewer than 3 stamps."""
    paths = _aligned_paths(poses, truth)
    if paths is None:
        return {}
    ref, est = paths
    common = sorted(set(poses) & set(truth))
    gaps = np.linalg.norm(est.positions_xyz - ref.positions_xyz,  # type: ignore[attr-defined]
                          axis=1)
    return dict(zip(common, (float(g) for g in gaps), strict=True))


def jump_count(errors: Mapping[int, float], threshold_m: float = JUMP_M) -> int:
    """The published poses (``errors``: stamp → aligned error, m) whose error rose by more
    than ``threshold_m`` from the pose published before it, however many untracked frames lie
    between: the content a user anchored moves that much at once, whatever the cause."""
    ordered = [errors[s] for s in sorted(errors)]
    return sum(b - a > threshold_m for a, b in itertools.pairwise(ordered))


#: a frame-to-frame wobble of the published position above this (mm) a user sees as a shake
JITTER_VISIBLE_MM = 20.0


@dataclass(frozen=True)
class Jitter:
    """How much the published position shakes from frame to frame: the second difference
    ‖p(i+1) − 2 p(i) + p(i−1)‖ over every three consecutive frames that all have one — an
    acceleration a frame, blind to steady motion and to drift, in millimetres."""

    rms_mm: float = math.nan
    median_mm: float = math.nan
    p95_mm: float = math.nan
    over_visible: int = 0          #: triples over :data:`JITTER_VISIBLE_MM`
    triples: int = 0


def jitter(positions: Mapping[int, np.ndarray], frames: Sequence[int]) -> Jitter:
    """The :class:`Jitter` of ``positions`` (key → xyz in metres) over ``frames``, the keys of
    consecutive camera frames in order (a triple counts only where all three are in
    ``positions``: a lost frame breaks it)."""
    second = []
    for a, b, c in zip(frames, frames[1:], frames[2:], strict=False):
        if a in positions and b in positions and c in positions:
            d = np.asarray(positions[c][:3]) - 2.0 * np.asarray(positions[b][:3]) \
                + np.asarray(positions[a][:3])
            second.append(float(np.linalg.norm(d)) * 1000.0)
    if not second:
        return Jitter()
    mm = np.asarray(second)
    return Jitter(float(np.sqrt(np.mean(mm ** 2))), float(np.median(mm)),
                  float(np.percentile(mm, 95)), int((mm > JITTER_VISIBLE_MM).sum()), mm.size)


#: a *revisit*: two tracked frames at least this many seconds apart ...
REVISIT_GAP_S = 10.0
#: ... whose true poses lie within this distance (m) ...
REVISIT_RADIUS_M = 0.3
#: ... and this rotation (degrees) of each other: the camera looks at one place again
REVISIT_ANGLE_DEG = 20.0


@dataclass(frozen=True)
class RevisitError:
    """How far virtual content anchored on a first visit appears moved on the return: for
    every revisit (a pair of tracked frames ≥ :data:`REVISIT_GAP_S` apart whose true poses lie
    within :data:`REVISIT_RADIUS_M` and :data:`REVISIT_ANGLE_DEG`), the translation error of
    the device's relative pose between the two against the truth's, in metres. A relative pose
    is the same in any frame, so no alignment enters: drift that a loop closure would remove
    shows here in full, a constant offset of the whole map not at all."""

    rms_m: float = math.nan
    median_m: float = math.nan
    p95_m: float = math.nan
    pairs: int = 0


def seen_alike(pose: np.ndarray, others: np.ndarray, radius_m: float, cos_max: float
               ) -> np.ndarray:
    """Which of the camera poses ``others`` (n, 4, 4) lie within ``radius_m`` of ``pose`` and
    turned from it by an angle whose cosine is at least ``cos_max``: cameras that see one
    place again (the angle from the trace of their relative rotation)."""
    near = np.linalg.norm(others[:, :3, 3] - pose[:3, 3], axis=1) <= radius_m
    cos = (np.einsum("ab,nab->n", pose[:3, :3], others[:, :3, :3]) - 1.0) / 2.0
    return np.asarray(near & (cos >= cos_max))


def relative_errors(pose: np.ndarray, truth: np.ndarray, others: np.ndarray,
                    others_truth: np.ndarray) -> np.ndarray:
    """The translation error (m) of ``pose``'s relative pose to each of ``others`` (n, 4, 4)
    against the truth's: the same in any frame the estimates share."""
    true_rel = np.linalg.inv(truth) @ others_truth
    est_rel = np.linalg.inv(pose) @ others
    off = np.linalg.inv(true_rel) @ est_rel
    return np.asarray(np.linalg.norm(off[:, :3, 3], axis=1))


def _revisit_summary(errors: list[np.ndarray]) -> RevisitError:
    """RMS, median, 95th percentile and count of the pairs' errors (none: no pair)."""
    if not errors:
        return RevisitError()
    e = np.concatenate(errors)
    return RevisitError(float(np.sqrt(np.mean(e ** 2))), float(np.median(e)),
                        float(np.percentile(e, 95)), int(e.size))


def revisit_error(poses: Mapping[int, np.ndarray], truth: Mapping[int, np.ndarray],
                  stamps: Iterable[int], gap_s: float = REVISIT_GAP_S,
                  radius_m: float = REVISIT_RADIUS_M,
                  angle_deg: float = REVISIT_ANGLE_DEG) -> RevisitError:
    """The :class:`RevisitError` over ``stamps`` (ns keys of tracked frames; those without a
    pose or a true pose are left out)."""
    keys = sorted(s for s in set(stamps) if s in poses and s in truth)
    if len(keys) < 2:
        return RevisitError()
    est = np.array([poses[s] for s in keys], dtype=np.float64)
    ref = np.array([truth[s] for s in keys], dtype=np.float64)
    ns = np.array(keys, dtype=np.int64)          # exact: seconds in floats round a gap off
    gap_ns = round(gap_s * 1e9)
    cos_max = math.cos(math.radians(angle_deg))
    errors: list[np.ndarray] = []
    for i in range(len(keys) - 1):
        later = np.flatnonzero(ns[i + 1:] - ns[i] >= gap_ns) + i + 1
        if not later.size:
            break                              # stamps are sorted: nothing later either
        js = later[seen_alike(ref[i], ref[later], radius_m, cos_max)]
        if not js.size:
            continue
        errors.append(relative_errors(est[i], ref[i], est[js], ref[js]))
    return _revisit_summary(errors)


def cross_device_revisit_error(first: Sequence[tuple[np.ndarray, np.ndarray]],
                               second: Sequence[tuple[np.ndarray, np.ndarray]],
                               radius_m: float = REVISIT_RADIUS_M,
                               angle_deg: float = REVISIT_ANGLE_DEG) -> RevisitError:
    """How far content one device placed appears moved to another: for every pair of a frame
    of ``first`` and a frame of ``second`` (each a (pose, true pose) pair, the poses as the
    devices published them, the truths in one world frame) whose true poses lie within
    ``radius_m`` and ``angle_deg``, the translation error of their relative pose against the
    truth's — the :class:`RevisitError` across two devices. No time gap: the devices are
    apart already. A relative pose is the same in any frame both poses share, so this
    measures whether the two devices' maps agree on the place; two devices each in a frame
    of its own (no merge yet) disagree by as much as their frames do."""
    return _revisit_summary(_cross_errors(first, second, radius_m, angle_deg))


@dataclass(frozen=True)
class RigidPart:
    """How much of a :func:`cross_device_revisit_error` one rigid motion of the second
    device's frames takes out (:func:`rigid_part`)."""

    #: 4×4, in the shared frame: the rigid motion that, applied to the second device's
    #: poses, fits them best
    motion: np.ndarray
    #: the cross-device error once the second device's poses are so moved: what no merge
    #: alignment, however good, takes out — the two maps bending apart
    left: RevisitError
    #: how far the motion moves the second device's frames at their pairs' centre (m) —
    #: not the motion's translation, a lever arm to the frame's origin far away
    moved_m: float = 0.0

    @property
    def turned_deg(self) -> float:
        """How far the motion turns them (degrees)."""
        return rotation_angle_deg(self.motion[:3, :3])


def rigid_part(first: Sequence[tuple[np.ndarray, np.ndarray]],
               second: Sequence[tuple[np.ndarray, np.ndarray]],
               radius_m: float = REVISIT_RADIUS_M,
               angle_deg: float = REVISIT_ANGLE_DEG) -> RigidPart:
    """The :func:`cross_device_revisit_error` of ``first`` and ``second`` split in two: the
    rigid motion of the second device's frames that makes it least, and what is left after
    it. A pair's error is how far the second frame's camera stands from where the first
    frame and the truth put it, ``Ea · Ta⁻¹ · Tb`` (its rotation does not enter), so the
    least error one rigid motion M leaves is a least-squares fit of M·pb to those positions
    over every pair (:func:`~twinslam.slam.back_end.depth_alignment.rigid_fit`, exact). A
    merge that placed the joining map a few centimetres off shows as a large ``moved_m`` and
    a small ``left``; two maps that bend apart along the walk, as the reverse. With no pair,
    the identity and an empty error; with fewer than three (no rigid motion fits them), the
    identity and the error as it is."""
    placed, wanted = [], []
    for est_a, ref_a, est_b, ref_b in _alike(first, second, radius_m, angle_deg):
        placed.append(est_b[:, :3, 3])
        wanted.append((est_a @ np.linalg.inv(ref_a) @ ref_b)[:, :3, 3])
    if not placed:
        return RigidPart(np.eye(4), RevisitError())
    p, q = np.concatenate(placed), np.concatenate(wanted)
    motion = rigid_fit(p, q) if len(p) >= 3 else np.eye(4)
    residual = np.linalg.norm(p @ motion[:3, :3].T + motion[:3, 3] - q, axis=1)
    moved = float(np.linalg.norm(q.mean(axis=0) - p.mean(axis=0))) if len(p) >= 3 else 0.0
    return RigidPart(motion, _revisit_summary([residual]), moved)


def cross_device_revisit_error_by_frame(
        first: Mapping[str, Sequence[tuple[np.ndarray, np.ndarray]]],
        second: Mapping[str, Sequence[tuple[np.ndarray, np.ndarray]]],
        radius_m: float = REVISIT_RADIUS_M, angle_deg: float = REVISIT_ANGLE_DEG
        ) -> RevisitError:
    """:func:`cross_device_revisit_error` over two devices' frames grouped by the map frame
    their poses are in (frame name → (pose, true pose) pairs): a frame of one device pairs
    only with the other's frames in the same map frame — two devices that were in one frame,
    then both moved into a third place's, have pairs in each, never across them."""
    errors = [e for frame in sorted(first.keys() & second.keys())
              for e in _cross_errors(first[frame], second[frame], radius_m, angle_deg)]
    return _revisit_summary(errors)


def _cross_errors(first: Sequence[tuple[np.ndarray, np.ndarray]],
                  second: Sequence[tuple[np.ndarray, np.ndarray]], radius_m: float,
                  angle_deg: float) -> list[np.ndarray]:
    """The relative-pose errors of every pair of :func:`cross_device_revisit_error`."""
    return [relative_errors(*pair) for pair in _alike(first, second, radius_m, angle_deg)]


def _alike(first: Sequence[tuple[np.ndarray, np.ndarray]],
           second: Sequence[tuple[np.ndarray, np.ndarray]], radius_m: float, angle_deg: float
           ) -> Iterator[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]:
    """For each frame of ``first`` (a (pose, true pose) pair) whose true pose ``second`` has
    frames within ``radius_m`` and ``angle_deg`` of: (its pose, its true pose, those frames'
    poses (n, 4, 4), their true poses) — the pairs the cross-device figures score."""
    if not first or not second:
        return
    est_b = np.array([e for e, _ in second], dtype=np.float64)
    ref_b = np.array([t for _, t in second], dtype=np.float64)
    cos_max = math.cos(math.radians(angle_deg))
    for est_a, ref_a in first:
        js = np.flatnonzero(seen_alike(ref_a, ref_b, radius_m, cos_max))
        if js.size:
            yield est_a, ref_a, est_b[js], ref_b[js]


def anchored_to_keyframes(poses: Mapping[int, np.ndarray],
                          keyframes_then: Mapping[int, Mapping[int, np.ndarray]],
                          keyframes_now: Mapping[int, np.ndarray]) -> dict[int, np.ndarray]:
    """Each frame's camera-to-map pose (frame id → 4×4) as content anchored to a keyframe sees
    it now: moved by that keyframe's correction since the frame was published —
    ``keyframes_now[k] · keyframes_then[f][k]⁻¹ · pose``, where ``keyframes_then[f]`` are the
    keyframe poses (id → camera-to-map) when frame ``f`` was published and ``k`` the newest of
    them no later than ``f`` (ids are frame indices: the keyframe the walk made last; the
    oldest one when all are later). A frame with no keyframe then or no anchor known now keeps
    its pose.

    ARCore's and ARKit's anchors follow the map's corrections this way. A pose kept in map
    coordinates does not: after a loop corrected a place, a revisit of it is measured against
    where the first visit was before the correction, and the :func:`revisit_error` of
    published poses counts the loop's correction of the drift as if it were the drift."""
    out: dict[int, np.ndarray] = {}
    for f, pose in poses.items():
        then = keyframes_then.get(f, {})
        known = [k for k in then if k in keyframes_now]
        if not known:
            out[f] = np.asarray(pose)
            continue
        earlier = [k for k in known if k <= f]
        k = max(earlier) if earlier else min(known)
        out[f] = np.asarray(keyframes_now[k]) @ np.linalg.inv(then[k]) @ np.asarray(pose)
    return out


def step_excess_mm(positions: Mapping[int, np.ndarray], truth: Mapping[int, np.ndarray],
                   frames: Sequence[int]) -> float:
    """The largest frame-to-frame step of ``positions`` beyond the truth's step over the same
    two frames, mm (keys as :func:`jitter`'s; a pair counts where both frames have a position
    and a true one): how far content anchored in that frame leaps at once more than the
    camera moved. NaN where no pair counts."""
    excess = [float(np.linalg.norm(np.asarray(positions[b][:3]) - np.asarray(positions[a][:3]))
                    - np.linalg.norm(np.asarray(truth[b][:3]) - np.asarray(truth[a][:3])))
              for a, b in itertools.pairwise(frames)
              if a in positions and b in positions and a in truth and b in truth]
    return max(excess) * 1000.0 if excess else math.nan
