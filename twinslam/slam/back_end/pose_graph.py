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
* a **prior** on the oldest keyframe (the gauge: the map frame stays where it is);
* in a map merged with another device's (:mod:`~twinslam.slam.back_end.map_merging`), the
  copies of that device's keyframes the walk was posed on as **anchors** (:class:`Anchors`):
  held by priors where that device's map has them, each tied to the walk's keyframes posed
  on its points — a loop of this walk bends it where no anchor holds it, and a loop of the
  other device, moving the anchors, moves the walk with them (:func:`follow_anchors`);
* a **loop across devices**: a loop factor between an anchor and a keyframe of the walk, as
  between two of its own — the walk came to a place the other device mapped, a drift away
  from where that device's keyframes have it, and bends towards them there.

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
from gtsam.symbol_shorthand import A, X

from twinslam.rotations import rotation_angle_deg
from twinslam.slam.sorted_ids import find_sorted

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
#: another device's map points a keyframe of the walk observed from which it is held to that
#: device's keyframe that brought them (:func:`follow_anchors`): the planner's lost-frame rule
#: counts a frame with fewer of the map's points lost — fewer did not serve its tracking
ANCHOR_SHARED_MIN = 15


@dataclass(frozen=True)
class LoopEdge:
    """A loop closed: keyframe ``new`` seen from keyframe ``old`` at relative pose
    ``measured`` (old⁻¹ · new)."""

    old: int
    new: int
    measured: np.ndarray
    inliers: int = LOOP_INLIERS_REF       #: the matches the measurement was fitted to


#: the low bits of a keyframe id that tell one walk's keyframes apart: a device's tag sits
#: above them (``foreign_keyframes.TAG_SHIFT``, which imports this module), and a tagged id
#: exceeds a gtsam Symbol's 56-bit index, where its walk's keyframes have one tag
WALK_ID_BITS = 40


def walk_key(kf_id: int) -> int:
    """The graph's key of a keyframe of the walk (every keyframe of one walk has one tag)."""
    return int(X(int(kf_id) & ((1 << WALK_ID_BITS) - 1)))


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
               earlier: Sequence[LoopEdge] = (), inliers: int = LOOP_INLIERS_REF,
               anchors: Anchors | None = None) -> LoopClosure:
    """The keyframe ``poses`` (id → camera-to-map, every keyframe of the walk) after closing
    the loop between keyframe ``old`` and keyframe ``new``, whose relative pose old⁻¹ · new
    was ``measured``; the oldest keyframe holds still. ``shared``: the map points pairs of
    keyframes (a, b), a < b, share — each pair of consecutive keyframes, and the covisible
    others (without: every step as stiff as its length makes it, no covisibility factor).
    ``earlier``: the loops closed before (those whose two keyframes are in ``poses`` hold).
    ``inliers``: the matches the new loop was measured on (how stiff its factor is).
    ``anchors``: another device's keyframes the walk was tracked on (a merged map's
    copies, :class:`Anchors`): held where they are, the walk's keyframes tied to them kept
    where they stand to them — the loop's correction bends the walk where nothing another
    device mapped holds it, as one loop closing over the place's map would. ``old`` may be
    one of the anchors (a loop across devices: the walk came to a place another device
    mapped, :func:`~twinslam.slam.back_end.loop_closing.loop_across`): held where it is,
    the loop bends this walk alone towards it."""
    held_old = anchors is not None and old in anchors.now
    if (old not in poses and not held_old) or new not in poses or old == new:
        raise ValueError(f"a loop joins two keyframes of the graph, got {old} and {new}")
    return _solved(*_walk_graph(poses, shared, [*earlier, LoopEdge(old, new, measured, inliers)],
                                anchors), poses)


@dataclass(frozen=True)
class Anchors:
    """Another device's keyframes a walk was tracked on, held where they are now."""

    before: Mapping[int, np.ndarray]      #: id → camera-to-map where the walk was posed on them
    now: Mapping[int, np.ndarray]         #: id → where they are held (moved or not)
    #: (walk keyframe, anchor) in id order → the anchor's points the walk keyframe observed
    ties: Mapping[tuple[int, int], int]
    #: walk keyframe → every point it observed
    observed: Mapping[int, int]

    def links(self, poses: Mapping[int, np.ndarray]) -> dict[tuple[int, int], int]:
        """The ties of ANCHOR_SHARED_MIN points or more between a keyframe of ``poses`` and
        an anchor."""
        return {(a, b): n for (a, b), n in self.ties.items() if n >= ANCHOR_SHARED_MIN and (
            (a in poses and b in self.now) or (b in poses and a in self.now))}


def follow_anchors(poses: Mapping[int, np.ndarray], anchors: Anchors,
                   shared: Mapping[tuple[int, int], int], earlier: Sequence[LoopEdge] = ()
                   ) -> LoopClosure | None:
    """A walk's keyframe ``poses`` (id → camera-to-map) after keyframes of another device's
    map that it was tracked on — the ``anchors`` — moved (that device closed a loop): None
    when no keyframe of the walk is tied to an anchor by ANCHOR_SHARED_MIN points.

    The graph is :func:`close_loop`'s without a new loop: the prior on the walk's oldest
    keyframe (the map's frame stays where it is), the walk's steps and covisibility
    (``shared``, pairs of the walk's keyframes), its ``earlier`` loops, and for each tie a
    factor holding the relative pose the two had before the anchor moved — as stiff as a
    step of that length and turn between keyframes sharing that many points, loosened by
    √(points the keyframe observed / the anchor's among them): a keyframe the device posed
    on another device's keyframes of a wall inherited their error in the share their points
    had in its pose, and moves so far towards where that wall now is, the walk bending
    between it and its start (one posed on twenty of the anchor's points among three hundred
    of its own map's barely moves). The anchors are held by priors too (another device's
    map, which this walk does not question). ORB-SLAM3 corrects the keyframes connected to
    a merge's or a loop's with the same kind of essential graph; here it is solved once a
    lender's loop reached the copies this map holds of its keyframes. A loop this walk closed
    with an anchor (``earlier``, a loop across devices) ties it as well."""
    if not poses or not _held_keys(poses, earlier, anchors):
        return None
    return _solved(*_walk_graph(poses, shared, earlier, anchors), poses)


def _walk_graph(poses: Mapping[int, np.ndarray], shared: Mapping[tuple[int, int], int] | None,
                loops: Sequence[LoopEdge], anchors: Anchors | None
                ) -> tuple[gtsam.NonlinearFactorGraph, gtsam.Values]:
    """The graph over the walk's keyframes: the prior on the oldest, the steps and the
    covisible pairs, the ``loops`` and the ``anchors`` (none: none); with its initial values,
    the poses as they are."""
    ids = sorted(poses)
    graph = gtsam.NonlinearFactorGraph()
    initial = gtsam.Values()
    for i in ids:
        initial.insert(walk_key(i), gtsam.Pose3(np.asarray(poses[i], dtype=np.float64)))
    graph.add(gtsam.PriorFactorPose3(walk_key(ids[0]), gtsam.Pose3(np.asarray(poses[ids[0]])),
                                     gtsam.noiseModel.Isotropic.Sigma(6, PRIOR_SIGMA)))
    _add_walk(graph, poses, shared)
    held = _held_keys(poses, loops, anchors)
    if anchors is not None:
        _add_anchors(graph, initial, poses, anchors, held)
    _add_loops(graph, poses, loops, held)
    return graph, initial


def _held_keys(poses: Mapping[int, np.ndarray], loops: Sequence[LoopEdge],
               anchors: Anchors | None) -> dict[int, int]:
    """The anchors the graph holds — those tied to a keyframe of ``poses`` and those a loop
    joins to one (a loop across devices) — each with its key A(j): tagged ids exceed a
    Symbol's index."""
    if anchors is None:
        return {}
    held = {k for pair in anchors.links(poses) for k in pair if k in anchors.now}
    held |= {edge.old for edge in loops
             if edge.old not in poses and edge.old in anchors.now and edge.new in poses}
    return {k: int(A(j)) for j, k in enumerate(sorted(held))}


def _add_anchors(graph: gtsam.NonlinearFactorGraph, initial: gtsam.Values,
                 poses: Mapping[int, np.ndarray], anchors: Anchors,
                 held: Mapping[int, int]) -> None:
    """Each anchor of ``held`` (id → key) held by a prior where it is now, and each tie a
    factor holding the relative pose the two had before the anchor moved, as
    :func:`follow_anchors` says."""
    def key(k: int) -> int:
        return held[k] if k in held else walk_key(k)

    prior = gtsam.noiseModel.Isotropic.Sigma(6, PRIOR_SIGMA)
    for k in sorted(held):
        now = gtsam.Pose3(np.asarray(anchors.now[k], dtype=np.float64))
        initial.insert(key(k), now)
        graph.add(gtsam.PriorFactorPose3(key(k), now, prior))
    for (a, b), n in sorted(anchors.links(poses).items()):
        pose_a = anchors.before[a] if a in held else poses[a]
        pose_b = anchors.before[b] if b in held else poses[b]
        relative = np.linalg.inv(pose_a) @ pose_b
        share = math.sqrt(max(anchors.observed.get(a if a in poses else b, n), n) / n)
        noise = gtsam.noiseModel.Diagonal.Sigmas(share * step_scale(n) * step_sigmas(relative))
        graph.add(gtsam.BetweenFactorPose3(key(a), key(b), gtsam.Pose3(relative), noise))


def _add_walk(graph: gtsam.NonlinearFactorGraph, poses: Mapping[int, np.ndarray],
              shared: Mapping[tuple[int, int], int] | None) -> None:
    """The walk's steps (consecutive ids) and its covisible pairs (≥ COVISIBLE_MIN shared
    points), each holding the relative pose the keyframes have now."""
    steps = set(itertools.pairwise(sorted(poses)))
    covisible = {pair for pair, n in (shared or {}).items()
                 if n >= COVISIBLE_MIN and pair[0] in poses and pair[1] in poses}
    for a, b in sorted(steps | covisible):
        relative = np.linalg.inv(poses[a]) @ poses[b]
        scale = 1.0 if shared is None else step_scale(shared.get((a, b), 0))
        step = gtsam.noiseModel.Diagonal.Sigmas(scale * step_sigmas(relative))
        graph.add(gtsam.BetweenFactorPose3(walk_key(a), walk_key(b), gtsam.Pose3(relative),
                                           step))


def _add_loops(graph: gtsam.NonlinearFactorGraph, poses: Mapping[int, np.ndarray],
               loops: Sequence[LoopEdge], held: Mapping[int, int]) -> None:
    """A loop factor for each of ``loops`` whose two keyframes are in ``poses`` — or whose
    old one is an anchor the graph holds (``held``: id → key; a loop across devices)."""
    for edge in loops:
        if (edge.old in poses or edge.old in held) and edge.new in poses:
            loop_noise = gtsam.noiseModel.Robust.Create(
                gtsam.noiseModel.mEstimator.Cauchy.Create(LOOP_CAUCHY),
                gtsam.noiseModel.Diagonal.Sigmas(loop_scale(edge.inliers)
                                                 * np.array(LOOP_SIGMAS)))
            old = held[edge.old] if edge.old in held else walk_key(edge.old)
            graph.add(gtsam.BetweenFactorPose3(old, walk_key(edge.new),
                                               gtsam.Pose3(np.asarray(edge.measured)),
                                               loop_noise))


def _solved(graph: gtsam.NonlinearFactorGraph, initial: gtsam.Values,
            poses: Mapping[int, np.ndarray]) -> LoopClosure:
    """Levenberg–Marquardt from ``initial``: the keyframes of ``poses`` where it leaves
    them, and their corrections."""
    before = graph.error(initial)
    result = gtsam.LevenbergMarquardtOptimizer(graph, initial).optimize()
    corrected = {i: result.atPose3(walk_key(i)).matrix() for i in sorted(poses)}
    corrections = {i: corrected[i] @ np.linalg.inv(poses[i]) for i in corrected}
    return LoopClosure(corrected, corrections, float(before), float(graph.error(result)))


def move_with_keyframes(positions: np.ndarray, reference: np.ndarray,
                        corrections: Mapping[int, np.ndarray]) -> np.ndarray:
    """The points at ``positions`` ((n, 3) in the map) each moved by its reference keyframe's
    correction (``reference``: (n,) keyframe ids); a point whose keyframe has none stays. One
    product for all of them: a loop moves a map's tens of thousands of points on the slot's
    path, where grouping them point by point in Python took ~100 ms a loop on the 7-Scenes
    walk under the profiler."""
    xyz = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
    if not corrections or not len(xyz):
        return xyz.copy()
    keyframes = np.sort(np.fromiter(corrections, dtype=np.int64, count=len(corrections)))
    at, found = find_sorted(keyframes, np.asarray(reference, dtype=np.int64).reshape(-1))
    c = np.stack([np.asarray(corrections[int(k)], dtype=np.float64)
                  for k in keyframes])[at[found]]
    moved = xyz.copy()
    moved[found] = np.einsum("nij,nj->ni", c[:, :3, :3], xyz[found]) + c[:, :3, 3]
    return moved
