"""Closing a loop: a pose graph over every keyframe the edge has seen, with GTSAM.

A walk that comes back to a place it saw long ago finds it again in the archive (place
recognition and a geometric check, :mod:`twinslam.slam.back_end.archive_relocalisation`), and
the pose the old place gives the new keyframe disagrees with the pose the walk carried to it:
the drift accumulated in between. ORB-SLAM's loop closing spreads that disagreement over the
loop with an essential-graph optimisation; here the graph reads like the math:

* a pose x_i (camera-to-map, ``gtsam.Pose3``) for every keyframe, archived or managed;
* between consecutive keyframes (by id: capture order) a **between factor** holding the
  relative pose the map has now — the walk's own motion, which the loop does not question —
  as stiff as its length and the two keyframes' covisibility make it: a tracker errs by a
  share of the way it went, so a long step or a large turn is trusted less than a short one;
  a step whose keyframes share many map points was tracked on common ground, one that shares
  none (the camera moved on between two uploads) is where drift could enter, and the loop's
  correction bends the walk there most;
* between two keyframes that are not consecutive but see many of the same points (≥
  COVISIBLE_MIN, ORB-SLAM's essential graph takes 100) a **covisibility factor** with their
  relative pose now, trusted as a step of that length and turn would be: keyframes that see
  one wall move together, or a correction that reaches one and not the other splits the wall
  in two (the walk comes back past the same place, and a keyframe of the way out beside one
  of the way back is far from it in capture order);
* a **loop factor** between the old keyframe and the new one, holding the relative pose the
  geometric check measured — stiffer than a step of the walk, as it is measured directly,
  under a Cauchy loss, so that a loop the rest of the graph contradicts cannot drag it far —
  and one for every loop closed before whose keyframes are still known: a new loop must not
  undo an older one (the graph is made anew for each loop, from the poses as they are);
* a **prior** on the oldest keyframe (the gauge: the map frame stays where it is).

Levenberg–Marquardt moves every pose so that the loop closes and the walk's steps bend as
little as they can; :func:`move_with_keyframes` then carries each point with its reference
keyframe's correction. No ROS, no threads: the edge runs it off the slot's critical path.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import gtsam
import numpy as np
from gtsam.symbol_shorthand import X

from twinslam.rotations import rotation_angle_deg

#: σ of a walk's step that goes nowhere (rad for the three rotations, m for the three
#: translations), and how it grows with the step: per metre of the step's length and per radian
#: of its turn. A tracker errs by a share of the path it walked, not by a constant a step: on
#: the corridor's exact depth the device's keyframe steps of 0.5 m were 4.5 mm off the truth's
#: at the median and 7.5 mm at the 90th percentile (1-1.5 %). A constant of 2 cm and 0.57° —
#: four times that — let a loop measured a degree off bend a short walk almost whole
#: (docs/results/map-consistency.md)
STEP_FLOOR = (0.001, 0.003)
STEP_PER_METRE = (0.005, 0.012)
STEP_PER_RADIAN = (0.02, 0.01)
#: σ of a loop's measured relative pose (a 3D–3D fit of the two keyframes' matched points) on
#: LOOP_INLIERS_REF inliers; fewer loosen it by √(LOOP_INLIERS_REF / inliers), more stiffen it
#: (a fit's information grows with its points): on the real revisit walk loops of fewer than
#: 200 inliers came out 0.9° and 2 cm off the truth's relative pose on average, those of 200
#: and more 0.4° and 1.1 cm; on the corridor's exact depth 0.1° and 0.2 cm against 0.04° and
#: 0.1 cm (docs/results/map-consistency.md)
LOOP_SIGMAS = (0.005, 0.005, 0.005, 0.01, 0.01, 0.01)
LOOP_INLIERS_REF = 200
#: the stiffest and the loosest a loop gets: LOOP_SIGMAS times these
LOOP_SCALE_RANGE = (0.5, 3.0)
#: the Cauchy kernel's width on loop factors, in σ: a loop the others and the walk contradict
#: by many σ pulls with a bounded force instead of one growing with its error (COVINS closes
#: its loops under a Cauchy loss)
LOOP_CAUCHY = 10.0
PRIOR_SIGMA = 1e-6
#: shared map points at which a step has step_sigmas; fewer loosen it by √(SHARED_REF / shared)
SHARED_REF = 100
#: the loosest a step gets (no shared point): step_sigmas times this
MAX_STEP_SCALE = 30.0
#: shared map points from which two keyframes that are not consecutive are held together
COVISIBLE_MIN = 100


@dataclass(frozen=True)
class LoopEdge:
    """A loop closed: keyframe ``new`` seen from keyframe ``old`` at relative pose
    ``measured`` (old⁻¹ · new)."""

    old: int
    new: int
    measured: np.ndarray
    inliers: int = LOOP_INLIERS_REF       #: the matches the measurement was fitted to


def loop_scale(inliers: int) -> float:
    """How much looser than LOOP_SIGMAS a loop measured on ``inliers`` matches is."""
    return float(np.clip(np.sqrt(LOOP_INLIERS_REF / max(inliers, 1)), *LOOP_SCALE_RANGE))


def step_scale(shared: int) -> float:
    """How much looser than :func:`step_sigmas` a walk's step is whose keyframes share
    ``shared`` points: 1 from SHARED_REF on, MAX_STEP_SCALE for none."""
    return float(np.clip(np.sqrt(SHARED_REF / max(shared, 0.1)), 1.0, MAX_STEP_SCALE))


def step_sigmas(relative: np.ndarray) -> np.ndarray:
    """The σ (three rotations in rad, three translations in m) of a step of the walk whose
    relative pose is ``relative`` (4×4): STEP_FLOOR, growing with the step's length and turn."""
    length = float(np.linalg.norm(relative[:3, 3]))
    turn = math.radians(rotation_angle_deg(relative[:3, :3]))
    rotation, translation = (floor + per_metre * length + per_radian * turn for floor, per_metre,
                             per_radian in zip(STEP_FLOOR, STEP_PER_METRE, STEP_PER_RADIAN,
                                               strict=True))
    return np.array([rotation] * 3 + [translation] * 3)


@dataclass(frozen=True)
class LoopClosure:
    poses: dict[int, np.ndarray]          #: keyframe id → corrected 4×4 camera-to-map
    #: keyframe id → its correction, corrected · before⁻¹ (what moves its points)
    corrections: dict[int, np.ndarray]
    initial_error: float
    final_error: float


def close_loop(poses: Mapping[int, np.ndarray], old: int, new: int,
               measured: np.ndarray, shared: Mapping[tuple[int, int], int] | None = None,
               earlier: Sequence[LoopEdge] = (), inliers: int = LOOP_INLIERS_REF
               ) -> LoopClosure:
    """The keyframe ``poses`` (id → camera-to-map, every keyframe of the walk) after closing
    the loop between keyframe ``old`` and keyframe ``new``, whose relative pose old⁻¹ · new
    was ``measured``; the oldest keyframe holds still. ``shared``: the map points pairs of
    keyframes (a, b), a < b, share — each pair of consecutive keyframes, and the covisible
    others (without: every step as stiff as its length makes it, no covisibility factor).
    ``earlier``: the loops closed before (those whose two keyframes are in ``poses`` hold).
    ``inliers``: the matches the new loop was measured on (how stiff its factor is)."""
    ids = sorted(poses)
    if old not in poses or new not in poses or old == new:
        raise ValueError(f"a loop joins two keyframes of the graph, got {old} and {new}")
    graph = gtsam.NonlinearFactorGraph()
    initial = gtsam.Values()
    for i in ids:
        initial.insert(X(i), gtsam.Pose3(np.asarray(poses[i], dtype=np.float64)))
    graph.add(gtsam.PriorFactorPose3(X(ids[0]), gtsam.Pose3(np.asarray(poses[ids[0]])),
                                     gtsam.noiseModel.Isotropic.Sigma(6, PRIOR_SIGMA)))
    steps = set(itertools.pairwise(ids))
    covisible = {pair for pair, n in (shared or {}).items()
                 if n >= COVISIBLE_MIN and pair[0] in poses and pair[1] in poses}
    for a, b in sorted(steps | covisible):
        relative = np.linalg.inv(poses[a]) @ poses[b]
        scale = 1.0 if shared is None else step_scale(shared.get((a, b), 0))
        step = gtsam.noiseModel.Diagonal.Sigmas(scale * step_sigmas(relative))
        graph.add(gtsam.BetweenFactorPose3(X(a), X(b), gtsam.Pose3(relative), step))
    for edge in [*earlier, LoopEdge(old, new, measured, inliers)]:
        if edge.old in poses and edge.new in poses:
            loop_noise = gtsam.noiseModel.Robust.Create(
                gtsam.noiseModel.mEstimator.Cauchy.Create(LOOP_CAUCHY),
                gtsam.noiseModel.Diagonal.Sigmas(loop_scale(edge.inliers)
                                                 * np.array(LOOP_SIGMAS)))
            graph.add(gtsam.BetweenFactorPose3(X(edge.old), X(edge.new),
                                               gtsam.Pose3(np.asarray(edge.measured)),
                                               loop_noise))
    before = graph.error(initial)
    result = gtsam.LevenbergMarquardtOptimizer(graph, initial).optimize()
    corrected = {i: result.atPose3(X(i)).matrix() for i in ids}
    corrections = {i: corrected[i] @ np.linalg.inv(poses[i]) for i in ids}
    return LoopClosure(corrected, corrections, float(before), float(graph.error(result)))


def move_with_keyframes(points: Mapping[int, np.ndarray], reference: Mapping[int, int],
                        corrections: Mapping[int, np.ndarray]) -> dict[int, np.ndarray]:
    """Each point (id → xyz in the map) moved by its reference keyframe's correction
    (``reference``: point id → keyframe id); a point without one stays. The points of one
    keyframe move in one product (a map holds tens of thousands)."""
    groups: dict[int, list[int]] = {}
    for pid in points:
        groups.setdefault(reference.get(pid, -1), []).append(pid)
    moved: dict[int, np.ndarray] = {}
    for kf, pids in groups.items():
        xyz = np.array([points[p] for p in pids], dtype=np.float64).reshape(-1, 3)
        c = corrections.get(kf)
        if c is not None:
            xyz = xyz @ np.asarray(c)[:3, :3].T + np.asarray(c)[:3, 3]
        moved.update(zip(pids, xyz, strict=True))
    return moved
