"""Carrying a closed loop's corrections into a map that kept changing while it was solved.

The pose graph (:mod:`twinslam.slam.back_end.pose_graph`) is solved off the slot's critical
path, on the keyframe poses of the moment the loop was found; by the time its answer is applied
the map has moved on — a bundle adjustment nudged the newest keyframes, new keyframes came in,
some left for the archive. Each correction is a rigid motion of the map frame
(corrected · before⁻¹), so it applies to a keyframe's pose as it is now by left
multiplication, whatever small change the pose had since; a keyframe newer than the graph
was placed by tracking on the drifted walk and takes the newest graph keyframe's correction
(as ORB-SLAM corrects the keyframes connected to the loop's current one). A map point moves
with its reference keyframe — here its oldest observer in the map, the keyframe that made it
or, once fused, the old place that saw it first.
"""

from __future__ import annotations

from collections.abc import Collection, Mapping

import numpy as np

from twinslam.slam.back_end.foreign_keyframes import tag_of
from twinslam.slam.back_end.keyframe_map import KeyFrameMap
from twinslam.slam.back_end.pose_graph import move_with_keyframes


def correction_for(corrections: Mapping[int, np.ndarray], kf_id: int,
                   walk: int = 0) -> np.ndarray | None:
    """Keyframe ``kf_id``'s correction by a loop of walk ``walk`` (its tag): its own, or —
    for a keyframe of the walk newer than every keyframe of the graph — the newest one's;
    None for an older keyframe the graph did not hold, and for a keyframe of another walk or
    another device's keyframe this map adopted (a loop moves its own walk; the others hold
    it as anchors)."""
    if tag_of(kf_id) != walk:
        return None
    own = corrections.get(kf_id)
    if own is not None:
        return own
    newest = max(corrections, default=None)
    return corrections[newest] if newest is not None and kf_id > newest else None


def farthest_move(m: KeyFrameMap, corrections: Mapping[int, np.ndarray],
                  walk: int = 0) -> float:
    """The farthest ``corrections`` (a loop of walk ``walk``) would move a keyframe of ``m``
    (m)."""
    moves = [float(np.linalg.norm((c @ kf.pose)[:3, 3] - kf.pose[:3, 3]))
             for kf_id, kf in m.keyframes.items()
             if (c := correction_for(corrections, kf_id, walk)) is not None]
    return max(moves, default=0.0)


def correct_map(m: KeyFrameMap, corrections: Mapping[int, np.ndarray]) -> None:
    """Move every keyframe of ``m`` by its correction (:func:`correction_for`) and every
    point with its reference keyframe (how far a keyframe moves: :func:`farthest_move`,
    asked before)."""
    move_keyframes(m, {k: c for k in m.keyframes
                       if (c := correction_for(corrections, k)) is not None})


def move_keyframes(m: KeyFrameMap, moves: Mapping[int, np.ndarray]) -> None:
    """Move the keyframes of ``m`` that ``moves`` names (id → 4×4 map-frame correction, as
    they are: adopted keyframes too) and every point with its reference keyframe, its oldest
    observer (:func:`~twinslam.slam.back_end.pose_graph.move_with_keyframes`).

    Only the points the moved keyframes observe are read: a point's reference is one of its
    observers, so no other point moves. A lender's loop moves a borrower's few copies of its
    keyframes, and each of a place's maps follows it: reading every point of the map for
    them took most of the following (``bench.place_walks`` under the profiler)."""
    for kf_id, c in moves.items():
        m.keyframes[kf_id].pose = c @ m.keyframes[kf_id].pose
    if not moves or not m.points:
        return
    observed = _observed_by(m, moves)
    ids = observed[m.columns.holds(observed)]
    if not len(ids):
        return
    points = m.points
    reference = np.fromiter((min(points[p].observers) for p in ids.tolist()),
                            dtype=np.int64, count=len(ids))
    m.set_positions(ids, move_with_keyframes(m.positions_of(ids), reference, moves))


def _observed_by(m: KeyFrameMap, keyframes: Collection[int]) -> np.ndarray:
    """The points of ``m`` any of ``keyframes`` observes, each once, ascending."""
    sets = [m.point_array(k) for k in keyframes]
    return np.unique(np.concatenate(sets)) if sets else np.zeros(0, dtype=np.int64)
