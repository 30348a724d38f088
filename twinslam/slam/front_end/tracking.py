"""Frame-by-frame tracking against a growing map of points (ORB-SLAM's Tracking, RGB-D case).

For each frame: ORB features → candidate map points (those the predicted pose — constant
velocity — projects into the image) → descriptor matches near each projection (ratio test,
Hamming cap) → a robust refinement of the predicted pose on the matched points' world
positions (PnP RANSAC when the prediction was too far off). The inliers are the frame's
observed map points M_f, the set the covisibility graph is built from. On a keyframe (the first
frame, too few tracked points or too long since the last) unmatched features with a depth
reading become new map points, back-projected with the estimated pose — as ORB-SLAM's RGB-D
mode creates "close" points from depth.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from twinslam.slam.descriptor_matching import match_descriptors
from twinslam.slam.front_end.local_map import LocalMap
from twinslam.slam.front_end.orb_extractor import Features, OrbExtractor
from twinslam.slam.front_end.pose_optimization import optimize_pose
from twinslam.slam.pose_plausibility import (
    MotionBounds,
    implausible_speed,
    implausible_step,
    non_finite,
)
from twinslam.slam.projection_matching import back_project, match_by_projection, visible_points
from twinslam.slam.viewing_directions import rays_from, seen_from_afar
from twinslam.slot_protocol import table1
from twinslam.slot_protocol.lost_frame_rule import MIN_INLIERS


@dataclass(frozen=True)
class TrackingConfig:
    n_features: int = 1000
    ratio: float = 0.8                 #: Lowe's ratio test on Hamming distances
    max_hamming: int = 64              #: of 256 bits
    search_radius_px: float = 20.0     #: match only near the predicted projection
    max_candidates: int = 3000         #: visible points matched per frame (most recently seen)
    #: of them, the share the device's own points (not the edge's map's) may take, and at
    #: least take where that many are in view; the edge's take the rest, either kind filling
    #: what the other leaves
    own_share: float = 0.5
    #: a point is searched for only where the frame's ray to it is within this of the
    #: direction the map saw it from (:mod:`twinslam.slam.viewing_directions`; ORB-SLAM's
    #: local map search uses 60°); 180: every point in the image is. 60° on four devices'
    #: walks of their own along the corridor (docs/results/shared-map.md, "Copies seen from
    #: elsewhere"): alone the edge counted 0.5–0.9 points more of their frames lost (four
    #: seeds); sharing the place with the cover by points as many lost and 15 more uploads
    max_view_angle_deg: float = 180.0
    min_inliers: int = MIN_INLIERS     #: fewer: the frame is not tracked (pose predicted)
    reprojection_px: float = 3.0       #: inlier threshold (pose refinement and RANSAC)
    min_inlier_ratio: float = 0.5      #: refined prediction keeps fewer: RANSAC instead
    keyframe_ratio: float = 0.6        #: new points when tracked < ratio × last keyframe's
    keyframe_every: int = 20           #: and at least this often (frames)
    depth_range_m: tuple[float, float] = (0.2, 8.0)
    #: the virtual stereo baseline each match's depth reading is weighed by in the motion
    #: model's pose refinement (ORB-SLAM2's RGB-D bf over fx; 0: the depth is not used there)
    depth_baseline_m: float = 0.0
    #: a match whose depth reads farther than this many baselines is refined on its pixel
    #: alone (ORB-SLAM2's ThDepth: a far reading's error grows with the square of its depth)
    close_baselines: float = 40.0
    fuse_radius_px: float = 60.0       #: keyframes look for old points this far off...
    fuse_max_hamming: int = 40         #: ...with a stricter descriptor match
    fuse_ratio: float = 0.7
    fuse_min_age: int = 30             #: "old": not seen in the last this many frames
    cull_after: int = 10               #: a new point not seen again within this many frames
    #: is culled (ORB-SLAM's recent map-point culling): no longer a match candidate
    relocalise: bool = False           #: a frame the motion model loses is matched against
    #: every active point by descriptor alone and solved by PnP RANSAC (ORB-SLAM's
    #: relocalisation, without its bag of words: the device's local map is small)
    relocalise_every: int = 3          #: while lost, relocalisation is tried on every this
    #: many-th frame (and at once on a new map): matching every map point costs 3-6 tracked
    #: frames (20-55 ms against 7-17 k points on 7-Scenes), and a device that tries it on
    #: every frame falls behind the camera exactly when it is lost
    #: the pose gate on a relocalisation (a pose solved against the whole map, no prior): at
    #: least this many RANSAC inliers after refinement. bench.relocalisation_gate on the
    #: 7-Scenes walk (maps of 100 and 500 frames, a SUN3D apartment as another place): no
    #: wrong pose (> 0.3 m from the truth) kept more than 17; ORB-SLAM3's 50 would keep only
    #: 19-61 % of the right ones (this tracker's 3-px RANSAC on Kinect v1 frames keeps fewer
    #: inliers than ORB-SLAM3's pose optimisation). Live, the paper's device on revisit-v15
    #: (3 seeds each, BENCHMARKS.md): no run jumped with 15, 20 or 30; 30 with a 10-frame
    #: probation lost the most frames. 20 still refuses the wrong pose the bench found
    reloc_min_inliers: int = 20
    #: ...and within reach of the last tracked pose: this far, plus this much a frame lost
    #: (0.05 m a frame is 1.5 m/s at 30 Hz, a walking user; the 7-Scenes hand-held camera
    #: peaks at 0.42 m/s over half a second)
    reloc_margin_m: float = 0.3
    reloc_reach_m_per_frame: float = 0.05
    #: frames after an accepted relocalisation that must track by the motion model before the
    #: device counts itself tracked — and uploads — again (ORB-SLAM3's probation; 0: none)
    reloc_probation_frames: int = 5
    reinit_after: int = 60             #: lost this many frames in a row: start afresh from
    #: depth at the last pose (no new points from a lost frame before: its pose is a guess;
    #: a device with ``own_points`` off never does, unless it switches them on)
    own_points: bool = True            #: keyframes add map points of their own (ORB-SLAM's
    #: tracking with its local mapping). False: the map comes from elsewhere
    #: (:meth:`Tracking.replace_map`, the paper's device tracking against the edge's map);
    #: only the first frame's depth makes points (a start-up map), and a long loss is not
    #: restarted from depth: the frame stays lost until relocalisation against the map succeeds
    #: the motion gate on every pose the motion model solves: a pose farther, or turned more,
    #: from the last posed frame than a hand-held or head-worn camera can move is refused and
    #: the frame lost (relocalisation, with its own gate, brings it back); None: no gate
    motion: MotionBounds | None = field(default_factory=MotionBounds)
    frame_rate_hz: float = table1.FRAME_RATE_HZ   #: the camera's, for the speed bound

    def __post_init__(self) -> None:
        if not 0.0 <= self.own_share <= 1.0:
            raise ValueError(f"own_share is a share of max_candidates, 0 to 1, not "
                             f"{self.own_share}")
        if not 0.0 < self.max_view_angle_deg <= 180.0:
            raise ValueError(f"max_view_angle_deg is an angle above 0 and at most 180°, not "
                             f"{self.max_view_angle_deg}")


@dataclass
class TrackedFrame:
    index: int
    pose: np.ndarray                   #: 4×4 camera-to-world estimate
    observed: np.ndarray               #: ids of the map points the frame observes (M_f)
    tracked: bool                      #: False: too few inliers, pose is the prediction
    keyframe: bool
    n_features: int
    n_matches: int
    features: Features | None = None  #: the frame's ORB features
    feature_points: np.ndarray | None = None   #: per feature, the map point it observes or -1
    relocalised: bool = False          #: tracked again after a relocalisation and its
    #: probation: the first frame the device counts as tracked after the loss
    inliers: int = 0                   #: matches the pose was solved with (0: not tracked,
    #: or the first frame, which defines the origin)
    on_probation: bool = False         #: posed since a relocalisation, not counted tracked yet
    refused: str = ""                  #: why the pose gate refused this frame's relocalisation
    implausible: str = ""              #: why the motion gate refused the pose the motion
    #: model solved for this frame (an impossible motion: the frame is lost)
    #: the motion model's refinement kept fewer than ``min_inlier_ratio`` of its matches and
    #: the pose came from PnP RANSAC instead: matches against the map that disagree with each
    #: other (a map inconsistent with itself, or a motion the model missed)
    pnp_ransac: bool = False


@dataclass(frozen=True)
class ProjectionSearch:
    """What the motion model's search by projection had to work with for one frame, as rows
    of the local map: the points its predicted pose sees, those of them it searched for (at
    most ``max_candidates``), and those it matched a feature to before the pose solve (the
    frame's inliers are of these); beside them, the points inside the image that the camera
    sees from too far off the direction the map saw them from to search. Where a frame's map
    points run short this tells a map that lacks the view from points in view left unsearched
    or unrecognised, and from points the map holds only as seen from elsewhere."""

    in_view: np.ndarray      #: rows predicted in the image, seen from about their direction
    searched: np.ndarray     #: of them, those searched for
    found: np.ndarray        #: rows matched to a feature
    turned: np.ndarray       #: rows predicted in the image, seen from too far off


NO_SEARCH = ProjectionSearch(*(np.zeros(0, dtype=np.int64),) * 4)


def _newest(rows: np.ndarray, last_seen: np.ndarray, n: int) -> np.ndarray:
    """The ``n`` of ``rows`` seen most recently (``last_seen``, one a row), in no order."""
    if n >= rows.size:
        return rows
    if n <= 0:
        return rows[:0]
    return rows[np.argpartition(-last_seen, n - 1)[:n]]


class Tracking:
    """Stateful tracker over one sequence; call :meth:`track` with frames in order."""

    def __init__(self, intrinsics: np.ndarray, config: TrackingConfig | None = None) -> None:
        self.config = config or TrackingConfig()
        self.k = np.asarray(intrinsics, dtype=np.float64)
        self.extractor = OrbExtractor(self.config.n_features)
        self.map = LocalMap()
        self._pose: np.ndarray | None = None          # camera-to-world of the last frame
        self._velocity = np.eye(4)                      # last frame-to-frame motion
        self._last_kf_tracked = 0
        self._last_kf_index = -1
        self._count = 0
        self._lost = 0                                  # frames lost in a row
        self._solved_by_ransac = False      # the last _solve_pose fell back to PnP RANSAC
        self._probation: list[tuple[int, np.ndarray]] = []   # (frame, ids) of new points
        #: the last frame's search by projection (NO_SEARCH: its first frame, or none since
        #: the map was replaced); a relocalisation's search of the whole map is not it. Its
        #: points in view are what a keyframe's fusion looks among
        self.last_search = NO_SEARCH
        self._new_map = False                           # replaced since the last relocalisation
        self._last_tracked: np.ndarray | None = None    # camera-to-world, last counted frame
        self._last_tracked_index = -1                   # ... and its index
        self._probation_left = 0                        # posed frames before it counts again
        self._back_after_probation = False              # the next counted frame is a recovery
        #: (frame, camera-to-world) of the posed frames of the last ``motion.speed_window``
        #: frames, the newest last: what the motion gate measures a new pose against
        self._posed: list[tuple[int, np.ndarray]] = []
        self._map_changed_at = -1             # the first frame tracked on a corrected map

    def track(self, color: np.ndarray, depth: np.ndarray | None) -> TrackedFrame:
        index = self._count
        self._count += 1
        feats = self.extractor.extract(color)
        assoc = np.full(len(feats.points), -1, dtype=np.int64)
        if self._pose is None:
            self._pose = np.eye(4)
            idx, new = self._add_points(feats, np.ones(len(feats.points), bool), depth,
                                        self._pose, index)
            assoc[idx] = new
            self._last_kf_tracked, self._last_kf_index = new.size, index
            return TrackedFrame(index, self._pose.copy(), new, True, True,
                                len(feats.points), 0, feats, assoc)
        predicted = self._pose @ self._velocity
        matched_feat, matched_ids = self._match(feats, predicted, color.shape[:2])
        pose, inliers = self._solve_pose(feats.points[matched_feat], matched_ids, predicted,
                                         depth)
        pnp_ransac = pose is not None and self._solved_by_ransac
        implausible = self.implausible(pose, index) if pose is not None else ""
        if implausible:
            pose, inliers = None, np.zeros(len(matched_ids), dtype=bool)
        relocalised, refused = False, ""
        if pose is None and self._relocalisation_due():
            self._new_map = False
            matched_feat, matched_ids, pose, inliers = self.relocalise(feats)
            if pose is not None:
                refused = self.gate(pose, int(inliers.sum()))
                if refused:
                    pose, inliers = None, np.zeros(len(matched_ids), dtype=bool)
            relocalised = pose is not None
        posed = pose is not None
        self._lost = 0 if posed else self._lost + 1
        on_probation, recovered = self._relocalisation_probation(posed, relocalised)
        tracked = posed and not on_probation
        if pose is None:                    # not tracked: the motion model's guess
            pose, inliers = predicted, np.zeros(len(matched_ids), dtype=bool)
        observed = matched_ids[inliers]
        n_inliers = len(observed)
        assoc[matched_feat[inliers]] = observed
        self.map.mark_seen(observed, index)
        keyframe = (len(observed) < self.config.keyframe_ratio * self._last_kf_tracked
                    or index - self._last_kf_index >= self.config.keyframe_every)
        reinitialised = self._lost >= self.config.reinit_after
        keyframe = keyframe and (tracked or reinitialised) and self.config.own_points
        if keyframe and depth is not None:
            free = np.ones(len(feats.points), bool)
            free[matched_feat[inliers]] = False
            fused_idx, fused = self._fuse(feats, free, pose, color.shape[:2], index)
            new_idx, new = self._add_points(feats, free, depth, pose, index)
            assoc[fused_idx], assoc[new_idx] = fused, new
            self._last_kf_tracked, self._last_kf_index = len(observed) + len(new), index
            observed = np.concatenate([observed, fused, new])
        self._velocity = (np.linalg.inv(self._pose) @ pose if posed and not relocalised
                          else np.eye(4))
        self._pose = pose
        if tracked:
            self._last_tracked, self._last_tracked_index = pose, index
        if posed:
            self._remember_posed(index, pose)
        self._cull(index)
        return TrackedFrame(index, pose.copy(), np.sort(observed), tracked, keyframe,
                            n_features=len(feats.points), n_matches=len(matched_ids),
                            features=feats, feature_points=assoc, relocalised=recovered,
                            inliers=n_inliers, on_probation=on_probation, refused=refused,
                            implausible=implausible,
                            pnp_ransac=pnp_ransac and tracked and not relocalised)

    @property
    def frames_tracked(self) -> int:
        return self._count

    @property
    def lost_in_a_row(self) -> int:
        """Frames without a pose since the last posed one (0: the last frame had one)."""
        return self._lost

    def replace_map(self, points: LocalMap, old_to_new: np.ndarray, corrected: bool = False
                    ) -> None:
        """Track from now on against ``points`` (the device's copy of a new edge map);
        ``old_to_new[i]`` is the new id of old point i, or -1 where it is gone. Points still on
        probation keep it; the motion model and the pose carry on. ``corrected``: the points
        moved (a map the edge optimised), so the next pose may move by the correction on top
        of the camera's motion (:class:`MotionBounds`' ``correction_m``); False for the same
        points, fewer or more of them."""
        self.map = points
        self._new_map = True
        if corrected:
            self._map_changed_at = self._count
        probation = []
        for frame, ids in self._probation:
            kept = old_to_new[ids]
            probation.append((frame, kept[kept >= 0]))
        self._probation = probation
        self.last_search = NO_SEARCH

    def move_frame(self, correction: np.ndarray) -> None:
        """The world frame was corrected by ``correction`` (4×4, a loop closed at the edge):
        every pose the tracker holds moves with it — the last pose the motion model starts
        from, the last counted one, the recent ones the motion gate measures from — so the next
        frame is solved in the corrected frame, as continuous as before (the frame-to-frame
        motion is relative and stays). The caller moves the points it tracks against."""
        c = np.asarray(correction, dtype=np.float64)
        if self._pose is not None:
            self._pose = c @ self._pose
        if self._last_tracked is not None:
            self._last_tracked = c @ self._last_tracked
        self._posed = [(i, c @ pose) for i, pose in self._posed]

    # -- steps ------------------------------------------------------------------------------

    def implausible(self, pose: np.ndarray, index: int) -> str:
        """Why the motion gate refuses ``pose`` (camera-to-world) solved by the motion model
        for frame ``index``, or "" to accept it: non-finite, or a step or turn from the last
        posed frame, or a speed over the last half second, no camera could have made
        (:mod:`twinslam.slam.pose_plausibility`; a map swapped in between adds its
        correction to the reach)."""
        bounds = self.config.motion
        if bounds is None:
            return ""
        if non_finite(pose):
            return "a non-finite pose"
        if not self._posed:
            return ""
        last_index, last = self._posed[-1]
        reason = implausible_step(last, pose, index - last_index, bounds,
                                  map_changed=self._map_changed_at > last_index)
        if reason:
            return reason
        first_index, first = self._posed[0]
        return implausible_speed(first, pose, index - first_index, self.config.frame_rate_hz,
                                 bounds, map_changed=self._map_changed_at > first_index)

    def _remember_posed(self, index: int, pose: np.ndarray) -> None:
        """Keep ``pose`` of frame ``index`` for the motion gate, with the posed frames of the
        last ``speed_window`` frames before it."""
        window = self.config.motion.speed_window if self.config.motion else 1
        self._posed = [(i, p) for i, p in self._posed if index - i < window]
        self._posed.append((index, pose))

    def gate(self, pose: np.ndarray, inliers: int) -> str:
        """Why a relocalised ``pose`` (camera-to-world, solved with ``inliers``) for the frame
        being tracked is refused, or "" to accept it: non-finite, too few inliers, or farther
        from the last frame counted as tracked than the device could have moved since."""
        cfg = self.config
        if non_finite(pose):
            return "a non-finite pose"
        if inliers < cfg.reloc_min_inliers:
            return f"{inliers} inliers, fewer than {cfg.reloc_min_inliers}"
        if self._last_tracked is not None:
            frames = self._count - 1 - self._last_tracked_index
            reach = cfg.reloc_margin_m + cfg.reloc_reach_m_per_frame * frames
            moved = float(np.linalg.norm(pose[:3, 3] - self._last_tracked[:3, 3]))
            if moved > reach:
                return (f"{moved:.2f} m from the last tracked pose, farther than "
                        f"{reach:.2f} m in {frames} frames")
        return ""

    def _relocalisation_probation(self, posed: bool, relocalised: bool) -> tuple[bool, bool]:
        """(this frame is on probation, this frame is the first counted after a relocalisation
        and its probation). A frame that loses its pose on probation ends it: lost again."""
        if relocalised:
            self._probation_left = self.config.reloc_probation_frames
            self._back_after_probation = True
        elif not posed:
            self._probation_left = 0
            self._back_after_probation = False
        if posed and self._probation_left > 0:
            self._probation_left -= 1
            return True, False
        recovered = posed and self._back_after_probation
        if recovered:
            self._back_after_probation = False
        return False, recovered

    def _relocalisation_due(self) -> bool:
        """Relocalise this lost frame: the first of a loss, every ``relocalise_every``-th
        after it, and the first after a new map (``_lost`` counts the frames lost before)."""
        cfg = self.config
        return cfg.relocalise and (self._new_map or self._lost % cfg.relocalise_every == 0)

    def _fuse(self, feats: Features, free: np.ndarray, pose: np.ndarray,
              shape: tuple[int, int], index: int) -> tuple[np.ndarray, np.ndarray]:
        """Old points that free features of a keyframe see again (ORB-SLAM's fusion of
        duplicates): searched wider and matched stricter than tracking, since after a revisit
        drift moves an old point tens of pixels. Marks them seen, clears those features, and
        returns (feature indices, point ids); they are not used for the pose."""
        cfg = self.config
        ids = self.last_search.in_view                # seen from the predicted pose
        ids = ids[self.map.last_seen[ids] < index - cfg.fuse_min_age]
        if ids.size > cfg.max_candidates:             # the most often confirmed ones
            ids = np.sort(ids[np.argpartition(-self.map.seen_count[ids], cfg.max_candidates)[
                :cfg.max_candidates]])
        cw = np.linalg.inv(pose)                      # re-projected with the estimate
        cam = self.map.positions[ids] @ cw[:3, :3].T + cw[:3, 3]
        in_front = cam[:, 2] > cfg.depth_range_m[0]
        ids, cam = ids[in_front], cam[in_front]
        uv = cam[:, :2] / cam[:, 2:3] * np.diag(self.k)[:2] + self.k[:2, 2]
        f_free = np.flatnonzero(free)
        if ids.size == 0 or f_free.size == 0:
            return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
        f_idx, c_idx = match_by_projection(feats.points[f_free], feats.descriptors[f_free], uv,
                                           self.map.descriptors[ids], cfg.fuse_radius_px,
                                           cfg.fuse_max_hamming, cfg.fuse_ratio, shape)
        free[f_free[f_idx]] = False
        fused = ids[c_idx]
        self.map.mark_seen(fused, index)
        return f_free[f_idx], fused

    def _cull(self, index: int) -> None:
        """Deactivate points created ``cull_after`` frames ago that no later frame saw."""
        while self._probation and index - self._probation[0][0] >= self.config.cull_after:
            _, ids = self._probation.pop(0)
            self.map.cull(ids[self.map.seen_count[ids] < 2])

    def _candidates(self, predicted: np.ndarray, shape: tuple[int, int]
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Ids of the points the predicted pose sees from about the direction the map saw
        them from; of them, the ones to search for (at most ``max_candidates``) and their
        predicted pixel positions; last, the ids inside the image seen from too far off."""
        ids, uv = visible_points(self.map.positions, self.map.active, predicted, self.k, shape,
                                 self.config.depth_range_m)
        turned = ids[:0]
        if self.config.max_view_angle_deg < 180.0:      # 180: no ray is farther off
            afar = seen_from_afar(self.map.views[ids], self.map.positions[ids],
                                  predicted[:3, 3], self.config.max_view_angle_deg)
            turned = ids[afar]
            ids, uv = ids[~afar], uv[~afar]
        if ids.size > self.config.max_candidates:
            keep = self._searched(ids)
            return ids, ids[keep], uv[keep], turned
        return ids, ids, uv, turned

    def _searched(self, ids: np.ndarray) -> np.ndarray:
        """Which of the points ``ids`` in view (more than ``max_candidates``) a frame searches
        for, as ascending indices into ``ids``: the most recently seen of the edge's map and
        of the device's own points, the device's own taking up to ``own_share`` of the
        searches and the edge's the rest, either filling what the other leaves.

        Ranked by sighting alone, the points the device made itself in its last slots — seen
        in every frame since — crowded the edge's out where a place is mapped densely: four
        devices on walks of their own along the corridor searched 36–53 % of the edge's points
        in view, and in the frames the edge counted lost (one seed) a median 42 of the 140 of
        their own edge map's and 10 of the 930 of other devices' copies, against 2506 of their
        own new points (``bench.place_walks --frames-csv``, docs/results/shared-map.md); the
        device tracked those frames, on points the edge never confirms. The edge's first,
        with nothing kept for the device's own, starved tracking instead where the edge's
        points in view disagree with the camera: the same walks' devices lost their pose in
        1–2.4 % of their frames."""
        cap = self.config.max_candidates
        from_edge, last_seen = self.map.from_edge[ids], self.map.last_seen[ids]
        edge, own = np.flatnonzero(from_edge), np.flatnonzero(~from_edge)
        n_own = min(own.size, max(int(self.config.own_share * cap), cap - edge.size))
        n_edge = min(edge.size, cap - n_own)
        return np.sort(np.concatenate([_newest(edge, last_seen[edge], n_edge),
                                       _newest(own, last_seen[own], n_own)]))

    def _match(self, feats: Features, predicted: np.ndarray, shape: tuple[int, int]
               ) -> tuple[np.ndarray, np.ndarray]:
        """(feature indices, map point ids) of accepted matches, one per feature and point.

        Searched near the predicted projections; if that finds too little (a jerk the motion
        model missed), once more with a three times wider window."""
        in_view, ids, uv, turned = self._candidates(predicted, shape)
        cfg = self.config
        for radius in (cfg.search_radius_px, 3 * cfg.search_radius_px):
            f_idx, c_idx = match_by_projection(feats.points, feats.descriptors, uv,
                                               self.map.descriptors[ids], radius,
                                               cfg.max_hamming, cfg.ratio, shape)
            if len(f_idx) >= 4 * cfg.min_inliers:
                break
        self.last_search = ProjectionSearch(in_view, ids, ids[c_idx], turned)
        return f_idx, ids[c_idx]

    def relocalise(self, feats: Features
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, np.ndarray]:
        """The relocalisation search for a frame the motion model lost: its features matched by
        descriptor against every active map point and the pose solved by PnP RANSAC without a
        prior: (feature indices, point ids, camera-to-world or None, inlier mask)."""
        matched_feat, matched_ids = self._match_all(feats)
        pose, inliers = self._solve_pose(feats.points[matched_feat], matched_ids, None)
        return matched_feat, matched_ids, pose, inliers

    def _match_all(self, feats: Features) -> tuple[np.ndarray, np.ndarray]:
        """(feature indices, point ids) matched by descriptor alone against every active
        point: the relocalisation search, used when the motion model lost the frame."""
        ids = np.flatnonzero(self.map.active)
        if ids.size < self.config.min_inliers or len(feats.points) == 0:
            return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
        f_idx, p_idx = match_descriptors(feats.descriptors, self.map.descriptors[ids],
                                         self.config.max_hamming, self.config.ratio)
        return f_idx, ids[p_idx]

    def _solve_pose(self, pixels: np.ndarray, ids: np.ndarray, predicted: np.ndarray | None,
                    depth: np.ndarray | None = None) -> tuple[np.ndarray | None, np.ndarray]:
        """Camera-to-world from 2D–3D matches, and the inlier mask; None if it fails.

        As ORB-SLAM tracks with its motion model: a robust refinement of the prediction, and
        RANSAC only when that keeps too few of the matches (a motion the model missed). With
        no prediction (relocalisation), RANSAC alone. With ``depth`` and a
        ``depth_baseline_m``, the refinement weighs each close match's depth reading too."""
        cfg = self.config
        self._solved_by_ransac = False
        if len(ids) < cfg.min_inliers:
            return None, np.zeros(len(ids), dtype=bool)
        world = self.map.positions[ids]
        if predicted is not None:
            cw = np.linalg.inv(predicted)                # world-to-camera prior
            depths = None
            if depth is not None and cfg.depth_baseline_m > 0.0:
                depths = depth_at(pixels, depth, cfg.depth_range_m)
                depths[depths > cfg.close_baselines * cfg.depth_baseline_m] = 0.0
            refined, mask = optimize_pose(world, pixels, self.k, cw, cfg.reprojection_px,
                                          depths, cfg.depth_baseline_m)
            kept = int(mask.sum())
            if kept >= cfg.min_inliers and kept >= cfg.min_inlier_ratio * len(ids):
                return np.linalg.inv(refined), mask
            rvec0, _ = cv2.Rodrigues(cw[:3, :3])
            tvec0 = cw[:3, 3].copy()
        else:
            rvec0, tvec0 = np.zeros((3, 1)), np.zeros(3)
        ok, rvec, tvec, inl = cv2.solvePnPRansac(
            world, pixels.astype(np.float64), self.k, None, rvec0.copy(), tvec0,
            useExtrinsicGuess=predicted is not None, iterationsCount=100,
            reprojectionError=self.config.reprojection_px, confidence=0.999,
            flags=cv2.SOLVEPNP_ITERATIVE)
        if not ok or inl is None or len(inl) < self.config.min_inliers:
            return None, np.zeros(len(ids), dtype=bool)
        mask = np.zeros(len(ids), dtype=bool)
        mask[inl.ravel()] = True
        rvec, tvec = cv2.solvePnPRefineLM(world[mask], pixels[mask].astype(np.float64), self.k,
                                          None, rvec, tvec)
        self._solved_by_ransac = True
        rot, _ = cv2.Rodrigues(rvec)
        cw = np.eye(4)
        cw[:3, :3], cw[:3, 3] = rot, tvec.ravel()
        return np.linalg.inv(cw), mask

    def _add_points(self, feats: Features, free: np.ndarray, depth: np.ndarray | None,
                    pose: np.ndarray, index: int) -> tuple[np.ndarray, np.ndarray]:
        """New map points for the free features that have a depth reading: (feature
        indices, new point ids)."""
        none = np.zeros(0, dtype=np.int64)
        if depth is None or not free.any():
            return none, none
        idx = np.flatnonzero(free)
        z = depth_at(feats.points[idx], depth, self.config.depth_range_m)
        good = z > 0
        idx, z = idx[good], z[good]
        if idx.size == 0:
            return none, none
        world = back_project(feats.points[idx], z, self.k, pose)
        ids = self.map.add(world, feats.descriptors[idx], index,
                           views=rays_from(pose[:3, 3], world))
        self._probation.append((index, ids))
        return idx, ids


def depth_at(points: np.ndarray, depth: np.ndarray, depth_range_m: tuple[float, float]
             ) -> np.ndarray:
    """The depth (metres) under each pixel, nearest pixel; 0 outside ``depth_range_m``."""
    px = np.round(np.asarray(points)).astype(int)
    h, w = depth.shape
    px[:, 0] = np.clip(px[:, 0], 0, w - 1)
    px[:, 1] = np.clip(px[:, 1], 0, h - 1)
    z = depth[px[:, 1], px[:, 0]].astype(np.float64)
    lo, hi = depth_range_m
    return np.where((z > lo) & (z < hi), z, 0.0)
