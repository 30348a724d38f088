"""Which archived keyframes to bring back into the managed map before the device needs them.

A keyframe the policy evicted is gone from the map the device tracks against, so the device
walking back into an evicted place fails there even though the edge still remembers the place
(:mod:`twinslam.slam.back_end.keyframe_archive`). Each slot the edge knows where the camera is
heading: the device's poses of the slot's tracked frames, continued at constant velocity
(:func:`edge_mapper.planning_world.extrapolate`). An archived keyframe is worth bringing back
when many of its map points fall in the camera's view from those predicted poses; the map
keeps V_max by evicting, in exchange, the keyframe that sees the least of that view (never
one integrated this slot). A swap is made only when the archived keyframe sees clearly more
of the coming view than the one it replaces, and only while the map's covisibility graph stays
connected (a disconnected map has no finite uncertainty, and its parts no common frame).

This is a step after the policy's decision (the policy chose U_k and C_k as the paper's rules
do); the restores and the evictions they cost are reported beside them.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from edge_mapper.planning_world import MAX_DEPTH_M, visible_mask
from twinslam.policies.restoring import MIN_VIEW_POINTS, choose_restores
from twinslam.slam.back_end.keyframe_archive import KeyFrameArchive
from twinslam.slam.back_end.keyframe_map import Incidence, shared_counts
from twinslam.slam.back_end.keyframe_slice import MapView
from twinslam.slam.camera import Camera
from twinslam.slam.sorted_ids import find_sorted
from twinslam.uncertainty.map_uncertainty import map_uncertainty

#: an archived keyframe is brought back only if this many of its points are in the coming
#: view, and only if it sees more than REPLACE_RATIO times what the keyframe it replaces
#: sees: the thresholds of the simulator's restoring rule (the same step in frames' terms)
MIN_VISIBLE = MIN_VIEW_POINTS


@dataclass(frozen=True)
class RestorePlan:
    restore: list[int]          #: archived keyframes back into the map, most useful first
    evict: list[int]            #: map keyframes evicted to make room for them


def view_scores(position_sets: Sequence[np.ndarray], poses: Sequence[np.ndarray],
                camera: Camera, max_depth_m: float = MAX_DEPTH_M) -> np.ndarray:
    """For each keyframe's points (``position_sets``, each N×3), how many of them ``camera``
    sees from the best of ``poses``. Every keyframe's points are tested in one pass a pose —
    a point's visibility is its own — not a pass a keyframe and pose: a merged map's archive
    holds hundreds of other devices' keyframes, and this runs every slot."""
    sizes = np.array([len(p) for p in position_sets], dtype=np.int64)
    best = np.zeros(len(sizes), dtype=np.int64)
    if not sizes.sum():
        return best
    points = np.concatenate([np.asarray(p, dtype=np.float64).reshape(-1, 3)
                             for p in position_sets])
    owner = np.repeat(np.arange(len(sizes)), sizes)
    for pose in poses:
        seen = np.bincount(owner[visible_mask(points, pose, camera, max_depth_m)],
                           minlength=len(sizes))
        best = np.maximum(best, seen)
    return best


def archived_in_view(archive: KeyFrameArchive, poses: Sequence[np.ndarray], camera: Camera,
                     slot: int) -> list[tuple[int, int]]:
    """(view score, id) of the archived keyframes with at least ``MIN_VISIBLE`` points in the
    view from ``poses``, most first; they count as useful in ``slot`` (the archive forgets
    them last)."""
    kfs = list(archive)
    scores = view_scores([kf.positions for kf in kfs], poses, camera).tolist()
    scored = sorted(((s, kf.id) for s, kf in zip(scores, kfs, strict=True)
                     if s >= MIN_VISIBLE), key=lambda sk: (-sk[0], sk[1]))
    archive.touch([k for _, k in scored], slot)
    return scored


class TrialWeights:
    """The covisibility weights (shared point counts, zero diagonal) of any map the restores
    may try — the map's keyframes with some left out and some archived ones added — as
    :func:`~twinslam.slam.back_end.keyframe_map.shared_counts` of their point sets would
    give them, without recounting the map's pairs for every trial: those are the map's
    ``counted`` incidence (:meth:`KeyFrameMap.incidence`, counted once a map), an archived
    keyframe's (``archived_sets``) are counted against the map once, when a trial first holds
    it. Each trial swap asked for the counts of the whole map again (~1 ms a trial, several a
    slot)."""

    def __init__(self, counted: Incidence, archived_sets: Mapping[int, np.ndarray]) -> None:
        self.map_index = {k: i for i, k in enumerate(counted.ids)}
        self.archived_sets = archived_sets
        self.counted = counted
        self.map_weights = counted.weights
        self._rows: dict[int, np.ndarray] = {}
        self._pairs: dict[tuple[int, int], int] = {}

    def of(self, keyframes: Sequence[int]) -> np.ndarray:
        """The weights of the map of ``keyframes`` (map keyframes and archived ones), in their
        order."""
        at = np.array([self.map_index.get(k, -1) for k in keyframes], dtype=np.int64)
        mapped, added = np.flatnonzero(at >= 0), np.flatnonzero(at < 0)
        w = np.zeros((len(keyframes), len(keyframes)))
        w[np.ix_(mapped, mapped)] = self.map_weights[np.ix_(at[mapped], at[mapped])]
        for n, i in enumerate(added.tolist()):
            row = self._row(keyframes[i])[at[mapped]]
            w[i, mapped] = w[mapped, i] = row
            for j in added[:n].tolist():
                w[i, j] = w[j, i] = self._both(keyframes[i], keyframes[j])
        return w

    def touches(self, kf: int, keyframes: Sequence[int]) -> bool:
        """Whether archived keyframe ``kf`` shares a point with any other of ``keyframes``
        (map keyframes and archived ones). One that shares none leaves a map of them in two
        parts whatever else it holds: most keyframes a shared place's restores try are
        another device's, in view but not yet tied to any the map holds, and each was scored
        as a whole map's weights and uncertainty."""
        mapped = [self.map_index[k] for k in keyframes if k in self.map_index]
        if mapped and self._row(kf)[mapped].any():
            return True
        return any(self._both(kf, k) for k in keyframes if k != kf and k not in self.map_index)

    def _both(self, a: int, b: int) -> int:
        """How many points archived keyframes ``a`` and ``b`` share, counted once a pair: a
        trial's touch and its weights ask for the same pairs, and so do the trials after it."""
        pair = (a, b) if a < b else (b, a)
        if pair not in self._pairs:
            self._pairs[pair] = int(np.intersect1d(self.archived_sets[a],
                                                   self.archived_sets[b]).size)
        return self._pairs[pair]

    def _row(self, kf: int) -> np.ndarray:
        """How many points archived keyframe ``kf`` shares with each map keyframe."""
        if kf not in self._rows:
            # the map's points it holds, by a sorted search of the incidence's sorted points
            # (a point named twice marks its column once); their columns summed as one
            # sparse product (slicing the columns out was most of a restore plan's time
            # where copies of a place stand in view)
            points = self.counted.points
            col, held = find_sorted(points, np.asarray(self.archived_sets[kf], dtype=np.int64))
            holds = np.zeros(len(points))
            holds[col[held]] = 1.0
            self._rows[kf] = np.asarray(self.counted.matrix @ holds).ravel()
        return self._rows[kf]


def plan_restores(m: MapView, archive: KeyFrameArchive, poses: Sequence[np.ndarray],
                  camera: Camera, vmax: int, limit: int, slot: int,
                  protected: Iterable[int] = ()) -> RestorePlan:
    """At most ``limit`` archived keyframes to restore, each with the map keyframe it
    replaces (none while the map has room below ``vmax``); ``protected`` keyframes (this
    slot's uploads) are never replaced. Archived keyframes in the coming view count as useful
    in ``slot`` (the archive forgets them last)."""
    if limit <= 0 or not poses:
        return RestorePlan([], [])
    candidates = archived_in_view(archive, poses, camera, slot)
    if not candidates:
        return RestorePlan([], [])
    counted = m.incidence(m.keyframe_ids())
    weights = TrialWeights(counted, {k: archive.get(k).point_ids for _, k in candidates})

    def connected(keyframes: list[int]) -> bool:
        # connected exactly when u(G) is finite: the check the map's uncertainty makes; a
        # candidate (the trial's last) that shares no point with the rest cannot be
        if len(keyframes) > 1 and not weights.touches(keyframes[-1], keyframes[:-1]):
            return False
        return math.isfinite(map_uncertainty(weights.of(keyframes)))

    scores = map_view_scores(m, counted, poses, camera)
    restore, evict = choose_restores(candidates, scores, vmax - len(m.keyframes), limit,
                                     set(protected), connected)
    return RestorePlan(restore, evict)


def plan_relocation_restores(m: MapView, archive: KeyFrameArchive,
                             poses: Sequence[np.ndarray], camera: Camera, vmax: int, limit: int,
                             slot: int, protected: Iterable[int] = ()) -> RestorePlan:
    """The managed map moved to where the edge relocalised a lost device (``poses``, found in
    the archive): up to ``limit`` archived keyframes that see most from there, those among
    them covisible with the best one. The map keyframes not connected to them by shared
    points leave (the device is not there; a map in two parts has no finite uncertainty),
    then the ones that see least of the view while the map is above ``vmax``. Nothing moves
    when a ``protected`` keyframe (this slot's uploads) would be cut off, or nothing of the
    archive is in view."""
    if limit <= 0 or not poses:
        return RestorePlan([], [])
    scored = archived_in_view(archive, poses, camera, slot)
    if not scored:
        return RestorePlan([], [])
    sets = {k: archive.get(k).point_ids for _, k in scored[:limit]}
    sets.update({k: m.point_array(k) for k in m.keyframes})
    best = scored[0][1]
    connected = _component(sets, best)
    restore = [k for _, k in scored[:limit] if k in connected]
    keep = set(protected)
    if not keep <= connected:
        return RestorePlan([], [])
    evict = sorted(k for k in m.keyframes if k not in connected)
    stay = [k for k in m.keyframes if k in connected]
    scores = map_view_scores(m, Incidence.of(stay, [sets[k] for k in stay]), poses, camera)
    while len(stay) + len(restore) > vmax:
        replaceable = [k for k in stay if k not in keep]
        if not replaceable:
            restore = restore[:max(vmax - len(stay), 0)]
            break
        victim = min(replaceable, key=lambda k: (scores[k], k))
        stay.remove(victim)
        evict.append(victim)
    final = {k: sets[k] for k in [*stay, *restore]}
    if not restore or not math.isfinite(map_uncertainty(shared_counts(list(final.values())))):
        return RestorePlan([], [])
    return RestorePlan(restore, evict)


def map_view_scores(m: MapView, counted: Incidence, poses: Sequence[np.ndarray],
                    camera: Camera) -> dict[int, int]:
    """:func:`view_scores` of the map keyframes ``counted`` holds (their point incidence,
    :meth:`KeyFrameMap.incidence`): each map point read and tested once a pose however many
    keyframes observe it (a point of a covisible map is in several), and counted for its
    keyframes by the incidence."""
    if not counted.ids:
        return {}
    positions = m.positions_of(counted.points)
    best = np.zeros(len(counted.ids), dtype=np.int64)
    for pose in poses:
        seen = counted.matrix @ visible_mask(positions, pose, camera, MAX_DEPTH_M).astype(
            np.float64)
        best = np.maximum(best, np.rint(seen).astype(np.int64))
    return dict(zip(counted.ids, best.tolist(), strict=True))


def _component(sets: dict[int, np.ndarray], start: int) -> set[int]:
    """The keyframes of ``sets`` connected to ``start`` through shared points."""
    ids = list(sets)
    shared = shared_counts([sets[k] for k in ids]) > 0
    index = {k: i for i, k in enumerate(ids)}
    seen, todo = {start}, [start]
    while todo:
        row = shared[index[todo.pop()]]
        for j in np.flatnonzero(row):
            if ids[j] not in seen:
                seen.add(ids[j])
                todo.append(ids[j])
    return seen
