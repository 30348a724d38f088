"""Adding an uploaded keyframe to the edge's map (docs/architecture.md §1 step 5; ORB-SLAM's
LocalMapping: associate, then create points).

A keyframe arrives with its features (pixel, ORB descriptor, depth) and, per feature, the id
the device associated it with (``Keyframe.map_point_ids``, 0 = none):

* an id below 2⁶³ is a **global map-point id** from the device's last ``MapUpdate``; if the
  point is still in the map the keyframe observes it;
* an id with the top bit set is a **device-local track id** of a feature the device followed
  across frames but the map does not have yet: the first keyframe carrying it creates the map
  point, and later keyframes with the same track id observe that same point — so two frames of
  one slot that saw the same new corner share it, as the covisibility weight needs;
* a feature with no usable id is matched by projection against the map points the keyframe's
  pose sees (the device's own matching, :mod:`twinslam.slam.projection_matching`);
* what is still unmatched and has a depth reading becomes a new map point, back-projected with
  the keyframe's pose.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from twinslam.slam.back_end.join_candidates import join_candidates
from twinslam.slam.back_end.keyframe_map import KeyFrameMap
from twinslam.slam.back_end.point_culling import PointCullingConfig, count_and_cull, facing
from twinslam.slam.keyframe import is_track
from twinslam.slam.projection_matching import back_project, match_by_projection, visible_points
from twinslam.slam.sorted_ids import find_sorted, unique_ids


@dataclass(frozen=True)
class LocalMappingConfig:
    search_radius_px: float = 15.0
    local_keyframes: int = 10          #: the local map: this many best covisible keyframes
    #: (the newest ones for a keyframe that shares no point yet)
    max_hamming: int = 50
    ratio: float = 0.8
    depth_range_m: tuple[float, float] = (0.2, 8.0)
    #: the points later keyframes should see and never find are removed
    #: (:mod:`twinslam.slam.back_end.point_culling`); None: every point stays until its last
    #: observer leaves (the edge's ``point_culling`` decides)
    culling: PointCullingConfig | None = None
    #: a feature about to make a new point whose depth puts it within this many metres (plus
    #: 2 % of its depth) of a local-map point in view that looks alike (``max_hamming``)
    #: observes that point instead: the corner the matching by pixel missed — its ratio test
    #: refuses a corner the map already holds twice, and each refusal would make one more
    #: copy. None: every unmatched feature with depth makes a point (the edge's
    #: ``point_fusion`` decides)
    join_radius_m: float | None = None


@dataclass(frozen=True)
class IntegrationReport:
    """How each of the keyframe's features ended up."""

    associated: int        #: by the device's global id
    tracked: int           #: by a device track id (``created_from_tracks`` of them new)
    created_from_tracks: int
    matched: int           #: by projection at the edge
    created: int           #: new points from depth
    unused: int            #: no match, no depth
    #: map points removed after this keyframe's view held them and they were not found once
    #: too often (:mod:`twinslam.slam.back_end.point_culling`)
    culled: int = 0
    #: features that would have made a new point beside a map point that looks alike, and
    #: observe that point instead (``LocalMappingConfig.join_radius_m``)
    joined: int = 0
    deferred: bool = False  #: held until an earlier slot finishes (counts above not known yet)
    #: why the edge's gate refused the keyframe ("" when integrated): nothing of it entered
    #: the map (:mod:`twinslam.slam.back_end.keyframe_gate`)
    refused: str = ""

    @classmethod
    def held(cls) -> IntegrationReport:
        return cls(0, 0, 0, 0, 0, 0, deferred=True)

    @classmethod
    def refusal(cls, reason: str) -> IntegrationReport:
        return cls(0, 0, 0, 0, 0, 0, refused=reason)


class LocalMapping:
    """Turns keyframes into map edits; remembers which map point each device track became."""

    def __init__(self, keyframe_map: KeyFrameMap, intrinsics: np.ndarray,
                 shape: tuple[int, int], config: LocalMappingConfig | None = None) -> None:
        self.map = keyframe_map
        self.k = np.asarray(intrinsics, dtype=np.float64)
        self.shape = shape
        self.config = config or LocalMappingConfig()
        self.track_points: dict[int, int] = {}    #: device track id → map point id
        #: tracks that became (or were matched to) a map point since the last ``take_new_tracks``
        self.new_tracks: dict[int, int] = {}

    def integrate(self, kf_id: int, pose: np.ndarray, keypoints: np.ndarray,
                  descriptors: np.ndarray, depths: np.ndarray, device_ids: np.ndarray
                  ) -> IntegrationReport:
        n = len(keypoints)
        if not (len(descriptors) == len(depths) == len(device_ids) == n):
            raise ValueError(f"keyframe {kf_id}: {n} keypoints but {len(descriptors)} "
                             f"descriptors, {len(depths)} depths, {len(device_ids)} ids")
        m = self.map
        m.add_keyframe(kf_id, pose)
        self._taken: dict[int, int] = {}          # point → feature, flushed into the map
        self._keypoints = np.asarray(keypoints, dtype=np.float64)
        d = np.asarray(depths, dtype=np.float64)
        self._depths = np.where(d > 0, d, math.nan)
        self._feature_point = np.zeros(n, dtype=np.int64)
        ids = np.asarray(device_ids, dtype=np.uint64)
        free = np.ones(n, dtype=bool)
        counts = dict(associated=0, tracked=0, created_from_tracks=0, matched=0, created=0,
                      joined=0)
        pending_tracks: list[int] = []
        # each reported id once: a track id (the device's own feature) or a map point's
        named = np.flatnonzero(ids)
        for i, dev, track in zip(named.tolist(), ids[named].tolist(),
                                 is_track(ids[named]).tolist(), strict=True):
            if track:
                pid = self.track_points.get(dev)
                if pid is not None and pid in m.points:
                    self._observe(kf_id, pid, free, i)
                    counts["tracked"] += 1
                else:
                    pending_tracks.append(i)       # created below if it has depth
            elif dev in m.points:
                self._observe(kf_id, dev, free, i)
                counts["associated"] += 1
        self._flush(kf_id)                        # the local map needs the keyframe's points
        in_view, uv = self._in_view(kf_id, pose)
        counts["matched"] = self._match(kf_id, keypoints, descriptors, free, in_view, uv)
        world, placeable = self._back_project(pose, depths)
        alike = self._alike_finder(kf_id, in_view, world, placeable, descriptors, depths, free)
        can_place = placeable.tolist()
        # the points this keyframe makes, by feature: named now (the map's next ids, in
        # order), put into the map at once before their observations are written
        making: list[int] = []
        first = m.next_point_id
        for i in pending_tracks:
            if free[i] and (same := alike(i)) is not None:
                self._observe(kf_id, same, free, i)
                counts["joined"] += 1
            if not free[i]:                   # matched to an existing point by projection
                self._remember_track(int(ids[i]), int(self._feature_point[i]))
            elif can_place[i]:
                created = first + len(making)
                making.append(i)
                self._remember_track(int(ids[i]), created)
                self._observe(kf_id, created, free, i)
                counts["tracked"] += 1
                counts["created_from_tracks"] += 1
        for i in np.flatnonzero(free & placeable).tolist():
            if (same := alike(i)) is not None:
                self._observe(kf_id, same, free, i)
                counts["joined"] += 1
            else:
                created = first + len(making)
                making.append(i)
                self._observe(kf_id, created, free, i)
                counts["created"] += 1
        made = set(m.add_points(world[making].reshape(-1, 3),
                                np.asarray(descriptors)[making]))
        self._flush(kf_id)
        unused = int(free.sum())
        # the map's points this keyframe found (those it made start counted)
        culled = self._cull(pose, m.keyframes[kf_id].points - made, in_view)
        return IntegrationReport(counts["associated"], counts["tracked"],
                                 counts["created_from_tracks"], counts["matched"],
                                 counts["created"], unused, len(culled), counts["joined"])

    def _alike_finder(self, kf_id: int, in_view: np.ndarray,
                      world: np.ndarray, placeable: np.ndarray, descriptors: np.ndarray,
                      depths: np.ndarray, free: np.ndarray) -> Callable[[int], int | None]:
        """A lookup by feature: the map point in view, not observed by the keyframe yet,
        nearest in descriptor among those within ``join_radius_m`` + 2 % of the depth of the
        feature's back-projected position (``world``, read where ``placeable``) and within
        ``max_hamming`` of its descriptor (None: none, or joining is off). Only features still
        ``free`` are looked up — one matched already is never asked for — and their
        candidates are found at once (:func:`~twinslam.slam.back_end.join_candidates.
        join_candidates`)."""
        radius = self.config.join_radius_m
        placed = np.flatnonzero(placeable & free)
        if radius is None or in_view.size == 0 or not placed.size:
            return lambda i: None
        reach = radius + 0.02 * np.asarray(depths, dtype=np.float64)[placed]
        positions = self.map.positions_of(in_view)
        # a tie in descriptor distance goes to the point the map has held longest (the lowest
        # id: ``in_view`` is sorted), the one most views have refined
        oldest_first = np.arange(len(in_view), dtype=np.int64)
        rows, counts = join_candidates(world[placed], reach, np.asarray(descriptors)[placed],
                                       positions, self.map.descriptors_of(in_view),
                                       oldest_first, self.config.max_hamming)
        if not len(rows):
            return lambda i: None
        # each feature's candidates a slice of one list, read only for the features asked
        ranked = in_view[rows].tolist()
        spans = {f: (end - n, end) for f, n, end in zip(placed.tolist(), counts.tolist(),
                                                        np.cumsum(counts).tolist(), strict=True)
                 if n}
        own = self.map.keyframes[kf_id].points

        def alike(i: int) -> int | None:
            start, end = spans.get(i, (0, 0))
            return next((p for p in ranked[start:end]
                         if p not in own and p not in self._taken), None)

        return alike

    def _cull(self, pose: np.ndarray, found: set[int], in_view: np.ndarray) -> list[int]:
        """The keyframe's views counted and the points never found again removed (none
        without ``culling``); the points a device track became stay resolvable until the
        slot's end prunes the table."""
        culling = self.config.culling
        if culling is None:
            return []
        held = in_view[facing(self.map, in_view, pose, culling.max_view_angle_deg)]
        return count_and_cull(self.map, found, held.tolist(), culling)

    def _remember_track(self, track: int, pid: int) -> None:
        self.track_points[track] = pid
        self.new_tracks[track] = pid

    def forget_tracks_gone(self) -> int:
        """Forget the device tracks whose map point left the map (culled, fused away, evicted
        with its last keyframe), so that the table stays the map's size; returns how many.
        The edge does this every slot for a table of tens of thousands of tracks on a long
        walk, of which a few hundred go: their points are looked up in the map's columns at
        once and only those gone are deleted, the rest keep their order."""
        table = self.track_points
        held = self.map.columns.holds(np.fromiter(table.values(), dtype=np.int64,
                                                  count=len(table)))
        if held.all():
            return 0
        gone = np.fromiter(table, dtype=np.uint64, count=len(table))[~held].tolist()
        for track in gone:
            del table[track]
        return len(gone)

    def take_new_tracks(self) -> dict[int, int]:
        """Track ids resolved since the last call (the device relabels them), and forget."""
        out, self.new_tracks = self.new_tracks, {}
        return out

    def _observe(self, kf_id: int, pid: int, free: np.ndarray, i: int) -> None:
        self._feature_point[i] = pid
        if pid not in self._taken and pid not in self.map.keyframes[kf_id].points:
            self._taken[pid] = i                 # one feature per point: the first
        free[i] = False

    def _flush(self, kf_id: int) -> None:
        """Write the collected observations into the map in one call."""
        if self._taken:
            rows = np.fromiter(self._taken.values(), dtype=np.int64, count=len(self._taken))
            self.map.observe_many(kf_id, list(self._taken), self._keypoints[rows].tolist(),
                                  self._depths[rows].tolist())
            self._taken = {}

    def _in_view(self, kf_id: int, pose: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(ids, pixels) of the local map's points the keyframe does not observe yet that its
        view holds. The local map, as in ORB-SLAM, is the points of the keyframes that share
        the most points with it (by the device's associations), or of the newest keyframes
        when it shares none: searching the whole map cost ~20 ms a keyframe."""
        m, cfg = self.map, self.config
        none = np.zeros(0, dtype=np.int64), np.zeros((0, 2))
        if not m.points:
            return none
        own = m.keyframes[kf_id].points
        shared = Counter(k for p in own for k in m.points[p].observers)
        del shared[kf_id]
        # the keyframes sharing the most points (ORB-SLAM's best covisible neighbours)
        neighbours = {k for k, _ in shared.most_common(cfg.local_keyframes)}
        if not neighbours:
            neighbours = set(m.keyframe_ids()[-cfg.local_keyframes - 1:]) - {kf_id}
        # their points, sorted, as arrays: each keyframe's ids are kept as one until the map
        # edits its observations, where a union of sets touched every id in Python
        local = unique_ids(np.concatenate([m.keyframes[k].observed()[0] for k in neighbours])
                           ) if neighbours else unique_ids(np.fromiter(m.points, np.int64,
                                                                       len(m.points)))
        mine = unique_ids(m.keyframes[kf_id].observed()[0])
        pids = local[~find_sorted(mine, local)[1]]
        if pids.size == 0:
            return none
        positions = m.positions_of(pids)
        vis, uv = visible_points(positions, np.ones(len(pids), dtype=bool), pose, self.k,
                                 self.shape, cfg.depth_range_m)
        return pids[vis], uv

    def _match(self, kf_id: int, keypoints: np.ndarray, descriptors: np.ndarray,
               free: np.ndarray, in_view: np.ndarray, uv: np.ndarray) -> int:
        """Free features matched to the points ``in_view`` (at pixels ``uv``)."""
        cfg = self.config
        f_free = np.flatnonzero(free)
        if f_free.size == 0 or in_view.size == 0:
            return 0
        desc = self.map.descriptors_of(in_view)
        f_idx, c_idx = match_by_projection(np.asarray(keypoints)[f_free],
                                           np.asarray(descriptors)[f_free], uv, desc,
                                           cfg.search_radius_px, cfg.max_hamming, cfg.ratio,
                                           self.shape)
        for fi, ci in zip(f_idx, c_idx, strict=True):
            self._observe(kf_id, int(in_view[ci]), free, int(f_free[fi]))
        return len(f_idx)

    def _back_project(self, pose: np.ndarray, depths: np.ndarray
                      ) -> tuple[np.ndarray, np.ndarray]:
        """Each feature's world position from its depth ((n, 3)) and whether its depth is in
        range ((n,) bool: a position is meaningful only there)."""
        lo, hi = self.config.depth_range_m
        z = np.asarray(depths, dtype=np.float64)
        world = back_project(self._keypoints, z, self.k, pose)
        with np.errstate(invalid="ignore"):
            placeable = (lo < z) & (z < hi)
        return world, placeable
