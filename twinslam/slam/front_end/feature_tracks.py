"""Feature tracks of a device that tracks only against the edge's map (``map_source: edge``).

In the paper's mode (its §III-A) the device builds no map: every pose comes from the points of
the edge's last map update alone. The edge still needs to know which of the slot's frames see
the same *new* features — the covisibility weights between candidate frames decide which of
them it uploads, and the uploaded keyframes' shared tracks become map points — so the device
follows the features the map does not explain from frame to frame: matched by projection with
the pose the map gave, new tracks back-projected from depth now and then. Tracks have no say in
the pose; they are ids the frame summaries and uploads carry, nothing more.

Stored like the map (:class:`~twinslam.slam.front_end.local_map.LocalMap` columns); the core labels
each row with a device-local track id and forgets rows older than the slots it can still upload.
"""

from __future__ import annotations

import numpy as np

from twinslam.slam.front_end.local_map import LocalMap
from twinslam.slam.front_end.orb_extractor import Features
from twinslam.slam.front_end.tracking import TrackingConfig, depth_at
from twinslam.slam.projection_matching import back_project, match_by_projection, visible_points
from twinslam.slam.viewing_directions import rays_from


class FeatureTracks:
    """Device-local tracks of the features the edge's map does not hold."""

    def __init__(self, intrinsics: np.ndarray, config: TrackingConfig) -> None:
        self.k = np.asarray(intrinsics, dtype=np.float64)
        self.config = config
        self.points = LocalMap(1024)
        self._last_new_index = -(10 ** 9)      #: frame that last started tracks
        self._last_new_seen = 0                #: tracks that frame saw (old and new)

    def __len__(self) -> int:
        return len(self.points)

    def observe(self, feats: Features, free: np.ndarray, pose: np.ndarray,
                depth: np.ndarray | None, index: int, shape: tuple[int, int]
                ) -> tuple[np.ndarray, np.ndarray, int]:
        """Follow the ``free`` features (those no map point explains) of frame ``index`` seen
        from ``pose``: (feature indices, track rows) of the matched and the new tracks, and
        how many rows are new (appended last).

        New tracks start, as the tracker's keyframes do, when the frame sees fewer than
        ``keyframe_ratio`` × the tracks the last starting frame saw, or ``keyframe_every``
        frames after it; only features with a depth reading start one."""
        cfg = self.config
        f_free = np.flatnonzero(free)
        none = np.zeros(0, dtype=np.int64)
        f_idx, rows = none, none
        if len(self.points) and f_free.size:
            ids, uv = visible_points(self.points.positions, self.points.active, pose, self.k,
                                     shape, cfg.depth_range_m)
            if ids.size > cfg.max_candidates:       # the most recently seen
                keep = np.argpartition(-self.points.last_seen[ids], cfg.max_candidates)[
                    :cfg.max_candidates]
                ids, uv = ids[keep], uv[keep]
            if ids.size:
                fi, ci = match_by_projection(feats.points[f_free], feats.descriptors[f_free],
                                             uv, self.points.descriptors[ids],
                                             cfg.search_radius_px, cfg.max_hamming, cfg.ratio,
                                             shape)
                f_idx, rows = f_free[fi], ids[ci]
                self.points.mark_seen(rows, index)
        seen = len(rows)
        starts = (seen < cfg.keyframe_ratio * self._last_new_seen
                  or index - self._last_new_index >= cfg.keyframe_every)
        if not starts or depth is None:
            return f_idx, rows, 0
        still = np.ones(len(feats.points), dtype=bool)
        still[f_idx] = False
        cand = f_free[still[f_free]]
        z = depth_at(feats.points[cand], depth, cfg.depth_range_m) if cand.size else \
            np.zeros(0)
        cand, z = cand[z > 0], z[z > 0]
        if cand.size == 0:             # nothing to start here: the next frame tries again
            return f_idx, rows, 0
        world = back_project(feats.points[cand], z, self.k, pose)
        new_rows = self.points.add(world, feats.descriptors[cand], index,
                                   views=rays_from(pose[:3, 3], world))
        self._last_new_index, self._last_new_seen = index, seen + len(new_rows)
        return (np.concatenate([f_idx, cand]), np.concatenate([rows, new_rows]),
                len(new_rows))

    def keep_rows(self, keep: np.ndarray) -> None:
        """Only the rows ``keep`` (ascending) stay, renumbered 0..len(keep) - 1."""
        self.points = self.points.take(keep)
