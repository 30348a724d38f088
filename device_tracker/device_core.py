"""The device's work, frame by frame and slot by slot, without DDS (docs/architecture.md §1 steps
1, 2, 4).

Where a frame's pose comes from is the device's ``map_source``:

* ``edge`` — the paper's device (its §III-A): every frame is tracked against the points of the
  edge's last ``MapUpdate`` alone; the device builds no map. Before the first update it tracks
  against a start-up map, the first frame's points back-projected from depth (frames tracked
  on it carry map version 0, so evaluations count them apart). A frame the map does not
  explain is lost, and stays lost until relocalisation against the map succeeds: what the
  edge keeps decides whether the device tracks. The features the map does not hold are
  followed as device-local **track ids** (:class:`~twinslam.slam.front_end.feature_tracks.
  FeatureTracks`), which the frame summaries and uploads carry for the edge's covisibility
  and triangulation; they never enter a pose.
* ``edge+local`` — an Edge-SLAM style device: the edge's last map plus the points the device
  created itself since then from depth on its own tracking keyframes (track ids too) — at most
  those of the last ``keep_slots`` slots, so the map stays bounded when the edge falls silent.

A paper's device lost for ``own_map_after`` frames in a row (0: never, the paper's) stops
waiting for the edge: the features it has been following as tracks — points back-projected
from depth at poses the edge's map gave, under the ids the edge already knows from the frame
summaries — join the map it tracks with, and it tracks on with them and the edge's points as
``edge+local`` does (relocalised against them at once when the motion model misses; started
afresh from depth after the tracker's ``reinit_after`` frames, as ORB-SLAM3 starts a new
map). Its frames have poses again, so the edge can ask for them and the map grows into the
ground the camera went to; without it a device lost in ground no upload has reached stays
lost, since a lost frame has no pose and is never uploaded. As soon as a frame is tracked by
``min_inliers`` of the edge's points, it is the paper's device again: its own points go back
to being tracks.

Track ids have the top bit set (:data:`~twinslam.slam.keyframe.TRACK_ID_BIT`). A lost frame is
relocalised against the map the device tracks with: the keyframes' points, matched by
descriptor, solved by PnP RANSAC. For each frame the device remembers M_f split by origin and,
for the frames of the last ``keep_slots`` slots, the features an upload needs (keypoints,
descriptors, depths, the id each feature observes).

When a ``MapUpdate`` answering slot s arrives, the map is swapped: the global points are the
update's (positions after the edge's bundle adjustment); the device's own points and tracks
the edge turned into map points (the update lists those track ids) take their global id, so
they are not kept twice — a duplicate would make the ratio test reject both; of the rest only
those created in slot s or later are kept (older ones were not uploaded, and the edge's map,
which the device follows, does not hold them). The tracker's pose and motion model carry on.
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass

import numpy as np

from device_tracker.messages import FrameRecord
from device_tracker.slot_clock import SlotClock
from twinslam.slam.front_end.feature_tracks import FeatureTracks
from twinslam.slam.front_end.local_map import LocalMap
from twinslam.slam.front_end.map_source import (
    EDGE,
    EDGE_LOCAL,
    check_map_source,
)
from twinslam.slam.front_end.tracking import Tracking, TrackingConfig, depth_at
from twinslam.slam.keyframe import KeyFramePayload, as_track_ids, is_track
from twinslam.slam.map_update import MapSnapshot
from twinslam.slam.sorted_ids import find_last
from twinslam.slam.viewing_directions import mean_viewing_directions
from twinslam.slot_protocol import table1


@dataclass(frozen=True)
class FrameResult:
    record: FrameRecord
    relocalised: bool
    slot_done: bool                #: this frame was its slot's last (take the slot now)
    lost_now: bool = False         #: tracking was lost at this frame (the one before tracked)
    recovered: bool = False        #: relocalised, or tracked again after untracked frames
    refused: str = ""              #: why the pose gate refused this frame's relocalisation
    on_probation: bool = False     #: posed after a relocalisation, not counted tracked yet
    #: why the motion gate refused the pose the motion model solved (the frame is lost)
    implausible: str = ""
    #: "started" or "ended" at this frame: tracking with the device's own points too ("": no
    #: change)
    own_map: str = ""


@dataclass(frozen=True)
class FrameStep:
    """What one stamped frame did to the slots (:meth:`DeviceTrackerCore.step`)."""

    unfinished: list[FrameRecord]  #: the slot its stamp ended (that slot's last frame never came)
    result: FrameResult
    finished: list[FrameRecord]    #: the slot this frame was the last of
    map_version: int


class DeviceTrackerCore:
    """Tracking against the edge's map — alone (``edge``) or with the device's own recent
    points (``edge+local``)."""

    def __init__(self, intrinsics: np.ndarray, slot_frames: int = table1.SLOT_FRAMES,
                 config: TrackingConfig | None = None, keep_slots: int = 2,
                 frame_rate_hz: float = table1.FRAME_RATE_HZ,
                 map_source: str = EDGE, own_map_after: int = 0) -> None:
        """``keep_slots``: the ended slots whose frames stay uploadable; the edge asks for a
        slot's frames during the next one, or later when the link was down meanwhile. A slot
        lasts ``slot_frames`` / ``frame_rate_hz`` seconds of frame stamps. ``map_source``:
        ``edge`` or ``edge+local`` (module docstring); it decides ``config.own_points``.
        ``own_map_after``: frames lost in a row before the paper's device maps by itself."""
        if keep_slots < 1:
            raise ValueError(f"keep_slots must be >= 1, got {keep_slots}")
        if own_map_after < 0:
            raise ValueError(f"own_map_after must be >= 0 frames, got {own_map_after}")
        reason = check_map_source(map_source)
        if reason:
            raise ValueError(f"map_source {map_source!r}: {reason}")
        self.map_source = map_source
        self.keep_slots = keep_slots
        self.k = np.asarray(intrinsics, dtype=np.float64)
        self.clock = SlotClock(slot_frames, frame_rate_hz)
        self.config = dataclasses.replace(config or TrackingConfig(relocalise=True),
                                          own_points=map_source == EDGE_LOCAL,
                                          frame_rate_hz=frame_rate_hz)
        self.tracking = Tracking(self.k, self.config)
        #: per map-point row: its global id or a track id (``is_track``)
        self.labels = np.zeros(0, dtype=np.uint64)
        self.created = np.zeros(0, dtype=np.int64)     #: per row: slot that created it
        #: the paper's device follows the features its map lacks apart from the map
        self.tracks = FeatureTracks(self.k, self.config) if map_source == EDGE else None
        self.track_labels = np.zeros(0, dtype=np.uint64)   #: per track row: its track id
        self.track_created = np.zeros(0, dtype=np.int64)   #: per track row: its slot
        self.map_version = 0
        #: whether a map update's points get the direction its keyframes saw them from (a
        #: few milliseconds an update): where the search leaves out points seen from too far
        #: off, or where a bench records what the frames saw from afar; else they stay NaN
        self.view_directions = self.config.max_view_angle_deg < 180.0
        #: CPU milliseconds of the map updates applied since the last frame: the next frame
        #: reports them with its own (its ``cpu_ms``), so that the frames' CPU adds up to the
        #: device's — an update runs on another thread, between two frames
        self._update_cpu_ms = 0.0
        #: the edge's frame correction of the map held (MapUpdate.frame_correction)
        self.frame_correction = np.eye(4)
        self.frames: list[FrameRecord] = []            #: the current slot's
        self.slot = 0                                  #: the slot frames are tracked in
        self._uploads: dict[int, KeyFramePayload] = {}      #: the last keep_slots slots' frames
        #: the images that go with those uploads, when the device uploads images too
        self._images: dict[int, object] = {}
        self._next_track = 1
        self.lost = False                              #: the last frame was not tracked
        self.own_map_after = own_map_after

    @property
    def own_map(self) -> bool:
        """A paper's device tracking with points of its own since a long loss: the only
        time it follows no feature tracks."""
        return self.map_source == EDGE and self.tracks is None

    @property
    def frame_count(self) -> int:
        return self.tracking.frames_tracked

    @staticmethod
    def warm_up(intrinsics: np.ndarray | None = None, shape: tuple[int, int] = (480, 640)) -> None:
        """Track two frames of noise at 2 m, so the compiled kernels are loaded before the
        first real frame arrives (the first call otherwise stalls tracking for seconds).
        Any camera compiles the same kernels; without one, a 640×480 camera with f = 525."""
        if intrinsics is None:
            intrinsics = np.array([[525.0, 0, 320], [0, 525, 240], [0, 0, 1]])
        rng = np.random.default_rng(0)
        image = rng.integers(0, 255, (*shape, 3), dtype=np.uint8)
        depth = np.full(shape, 2.0, dtype=np.float32)
        tracking = Tracking(intrinsics, TrackingConfig(relocalise=True))
        for _ in range(2):
            tracking.track(image, depth)

    def ends_slot_before(self, stamp: float) -> bool:
        """A frame of ``stamp`` starts a later slot while the current one still holds
        frames: its last frame never came, so take it now (before tracking this frame)."""
        return bool(self.frames) and self.clock.slot_of(stamp) > self.slot

    # -- frames ------------------------------------------------------------------------------

    def track(self, color: np.ndarray, depth: np.ndarray | None, stamp: float,
              image: object | None = None) -> FrameResult:
        """Track one frame; ``image`` (e.g. its colour message) is kept with the frame's
        upload, for a device that sends the frame itself with its keyframe."""
        if self.ends_slot_before(stamp):
            raise RuntimeError(f"slot {self.slot} must be taken before a frame of a later slot "
                               "is tracked (ends_slot_before)")
        # a late stamp (older than the current slot) joins the current slot: ended is ended
        self.slot = max(self.slot, self.clock.slot_of(stamp))
        started = time.thread_time()             # this thread's CPU, not the machine's wall
        own_map = ""
        if self._lost_too_long():
            self._start_own_map()
            own_map = "started"
        out = self.tracking.track(color, depth)
        if image is not None:
            self._images[out.index] = image
        self._label_new_points()
        ids = self.labels[out.observed]
        on_track = is_track(ids)
        assert out.features is not None and out.feature_points is not None
        assoc = out.feature_points
        point_ids = np.zeros(len(assoc), dtype=np.uint64)      # 0: the feature observes none
        matched = assoc >= 0
        point_ids[matched] = self.labels[assoc[matched]]      # (the map may hold no point)
        track_ids = ids[on_track]
        if self.tracks is not None and out.tracked:
            f_idx, rows, n_new = self.tracks.observe(out.features, assoc < 0, out.pose, depth,
                                                     out.index, color.shape[:2])
            self._label_new_tracks(n_new)
            followed = self.track_labels[rows]
            point_ids[f_idx] = followed
            track_ids = np.concatenate([track_ids, followed])
        record = FrameRecord(out.index, stamp, out.pose, out.tracked,
                             map_point_ids=np.sort(ids[~on_track]),
                             track_ids=np.sort(track_ids), slot=self.slot,
                             relocalised=out.relocalised, inliers=out.inliers,
                             map_version=self.map_version,
                             cpu_ms=(time.thread_time() - started) * 1000.0
                             + self._update_cpu_ms,
                             pose_refused=bool(out.refused or out.implausible),
                             pnp_ransac=out.pnp_ransac, matches=out.n_matches)
        self._update_cpu_ms = 0.0
        self.frames.append(record)
        slot = self.slot
        depths = (depth_at(out.features.points, depth, self.config.depth_range_m)
                  if depth is not None else np.zeros(len(assoc)))
        self._uploads[out.index] = KeyFramePayload(
            out.index, slot, stamp, out.pose, self.k, out.features.points,
            depths.astype(np.float32), out.features.descriptors, point_ids.astype(np.uint64))
        was_lost, self.lost = self.lost, not out.tracked
        if self.own_map and out.tracked and (~on_track).sum() >= self.config.min_inliers:
            self._end_own_map()          # the edge's map explains the view again
            own_map = "ended"
        return FrameResult(record, out.relocalised, self.clock.is_last(stamp),
                           lost_now=self.lost and not was_lost,
                           recovered=out.tracked and (out.relocalised or was_lost),
                           refused=out.refused, on_probation=out.on_probation, own_map=own_map,
                           implausible=out.implausible)

    def step(self, color: np.ndarray, depth: np.ndarray | None, stamp: float,
             image: object | None = None) -> FrameStep:
        """Track a frame with its slot bookkeeping: a slot whose last frame never came ends at
        the first frame of a later slot; a slot's last frame ends it."""
        unfinished = self.take_slot() if self.ends_slot_before(stamp) else []
        result = self.track(color, depth, stamp, image)
        finished = self.take_slot() if result.slot_done else []
        return FrameStep(unfinished, result, finished, self.map_version)

    def take_slot(self) -> list[FrameRecord]:
        """The finished slot's frames (F_k, each with its ``slot``); forgets the uploads of
        slots more than ``keep_slots`` - 1 before it."""
        frames, self.frames = self.frames, []
        if frames:
            oldest = self.slot - self.keep_slots + 1
            self._uploads = {f: u for f, u in self._uploads.items() if u.slot >= oldest}
            self._images = {f: i for f, i in self._images.items() if f in self._uploads}
            if self.tracks is None:
                self._forget_own_points_before(oldest)
            else:                     # the start-up map stays until the edge's map replaces it
                self._forget_tracks_before(oldest)
            self.slot += 1
        return frames

    def _lost_too_long(self) -> bool:
        """A paper's device has lost the last ``own_map_after`` frames in a row."""
        return (self.own_map_after > 0 and self.tracks is not None
                and self.tracking.lost_in_a_row >= self.own_map_after)

    def _start_own_map(self) -> None:
        """Track as ``edge+local`` from this frame on, the feature tracks joining the map as
        the device's own points (their ids and slots kept)."""
        assert self.tracks is not None
        self.tracking.config = dataclasses.replace(self.config, own_points=True)
        old, tracks = self.tracking.map, self.tracks.points
        points = old.take(np.arange(len(old)))
        rows = points.add(tracks.positions, tracks.descriptors, 0, views=tracks.views)
        points.last_seen[rows] = tracks.last_seen
        points.seen_count[rows] = tracks.seen_count
        points.active[rows] = tracks.active
        self.tracking.replace_map(points, np.arange(len(old)))
        self.labels = np.concatenate([self.labels, self.track_labels])
        self.created = np.concatenate([self.created, self.track_created])
        self.tracks = None
        self.track_labels = np.zeros(0, dtype=np.uint64)
        self.track_created = np.zeros(0, dtype=np.int64)

    def _end_own_map(self) -> None:
        """The paper's device again: only the edge's points stay in the map it tracks with;
        its own points go back to being feature tracks."""
        self.tracking.config = self.config
        own = is_track(self.labels)
        self.tracks = FeatureTracks(self.k, self.config)
        self.tracks.points = self.tracking.map.take(np.flatnonzero(own))
        self.track_labels, self.track_created = self.labels[own], self.created[own]
        self._keep_points(np.flatnonzero(~own))

    def _forget_tracks_before(self, oldest_slot: int) -> None:
        """Tracks started before ``oldest_slot`` go: no frame the edge may still ask for
        needs them, and within a slot is where the edge compares them."""
        keep = np.flatnonzero(self.track_created >= oldest_slot)
        if keep.size < self.track_created.size:
            self._keep_tracks(keep)

    def _keep_tracks(self, keep: np.ndarray) -> None:
        assert self.tracks is not None
        self.tracks.keep_rows(keep)
        self.track_labels, self.track_created = self.track_labels[keep], self.track_created[keep]

    def set_map_source(self, map_source: str) -> None:
        """Track with ``map_source`` from the next frame on. Going to ``edge`` drops the
        device's own points from the map it tracks with (unless no map update came yet: they
        are its start-up map); going to ``edge+local`` lets its keyframes make points again."""
        reason = check_map_source(map_source)
        if reason:
            raise ValueError(f"map_source {map_source!r}: {reason}")
        if map_source == self.map_source:
            return
        self.map_source = map_source
        self.config = dataclasses.replace(self.config, own_points=map_source == EDGE_LOCAL)
        self.tracking.config = self.config
        self.track_labels = np.zeros(0, dtype=np.uint64)
        self.track_created = np.zeros(0, dtype=np.int64)
        if map_source == EDGE_LOCAL:
            self.tracks = None
            return
        self.tracks = FeatureTracks(self.k, self.config)
        if self.map_version > 0:
            self._keep_points(np.flatnonzero(~is_track(self.labels)))

    def _forget_own_points_before(self, oldest_slot: int) -> None:
        """Bound the local map while the edge is silent: the device's own points created
        before ``oldest_slot`` go (their frames can no longer be uploaded, so the edge's map
        will not hold them). With the edge answering, each map update prunes them sooner."""
        stale = is_track(self.labels) & (self.created < oldest_slot)
        if stale.any():
            self._keep_points(np.flatnonzero(~stale))

    def _keep_points(self, keep: np.ndarray) -> None:
        """Only the map rows ``keep`` (ascending) stay in the map the device tracks with."""
        old = self.tracking.map
        old_to_new = np.full(len(old), -1, dtype=np.int64)
        old_to_new[keep] = np.arange(keep.size)
        self.tracking.replace_map(old.take(keep), old_to_new)
        self.labels, self.created = self.labels[keep], self.created[keep]

    def upload(self, frame_id: int) -> KeyFramePayload | None:
        """The keyframe content of a frame of the last ``keep_slots`` slots; None if it is
        gone."""
        return self._uploads.get(frame_id)

    def upload_image(self, frame_id: int) -> object | None:
        """The image kept with an upload (``track(..., image=...)``); None if none or gone."""
        return self._images.get(frame_id)

    def _new_track_ids(self, count: int) -> np.ndarray:
        """``count`` fresh device-local ids, marked as tracks."""
        ids = np.arange(self._next_track, self._next_track + count, dtype=np.uint64)
        self._next_track += count
        return as_track_ids(ids)

    def _label_new_points(self) -> None:
        n_old, n = len(self.labels), len(self.tracking.map)
        if n == n_old:
            return
        self.labels = np.concatenate([self.labels, self._new_track_ids(n - n_old)])
        self.created = np.concatenate([self.created, np.full(n - n_old, self.slot, np.int64)])

    def _label_new_tracks(self, count: int) -> None:
        if count:
            self.track_labels = np.concatenate([self.track_labels, self._new_track_ids(count)])
            self.track_created = np.concatenate([self.track_created,
                                                 np.full(count, self.slot, np.int64)])

    # -- map updates -------------------------------------------------------------------------

    def apply_map_update(self, update: MapSnapshot, slot: int) -> bool:
        """Swap in the edge's map of slot ``slot``; False (and nothing changes) for a version
        not newer than the one held. The CPU it took (this thread's) counts in the next
        frame's ``cpu_ms``."""
        if update.version <= self.map_version:
            return False
        started = time.thread_time()
        self._swap_in(update, slot)
        self._update_cpu_ms += (time.thread_time() - started) * 1000.0
        return True

    def _swap_in(self, update: MapSnapshot, slot: int) -> None:
        old, now = self.tracking.map, max(self.frame_count - 1, 0)
        if len(update.track_ids):
            self.labels = relabelled(self.labels, update.track_ids, update.track_point_ids)
        own = is_track(self.labels)
        moved_frame = update.frame_correction @ np.linalg.inv(self.frame_correction)
        if not np.allclose(moved_frame, np.eye(4), atol=1e-12):
            # a loop closed at the edge corrected the map's frame: what the device holds of
            # the old frame — its own points, its tracks, its poses — moves with it, so it
            # never tracks on the corrected map and its own uncorrected copy at once
            old.move(moved_frame)
            if self.tracks is not None:
                self.tracks.points.move(moved_frame)
            self.tracking.move_frame(moved_frame)
        self.frame_correction = np.asarray(update.frame_correction, dtype=np.float64)
        if self.tracks is not None:
            # the paper's device tracks against the update alone: no point of its own stays
            # (the start-up map included); tracks the edge resolved are map points now
            resolved = np.isin(self.track_labels, update.track_ids)
            self._keep_tracks(np.flatnonzero(~resolved & (self.track_created >= slot)))
            own[:] = False
        keep = np.flatnonzero(own & (self.created >= slot) & old.active)
        points = LocalMap(max(len(update.point_ids) + keep.size, 16))
        views = (mean_viewing_directions(update.point_ids, update.positions,
                                         update.keyframe_poses, update.keyframe_points)
                 if self.view_directions else None)
        new_global = points.add(update.positions, update.descriptors, now, from_edge=True,
                                views=views)
        new_track = points.add(old.positions[keep], old.descriptors[keep], now,
                               views=old.views[keep])
        old_to_new = np.full(len(old), -1, dtype=np.int64)
        old_to_new[keep] = new_track
        held, at = rows_of_points(self.labels, update.point_ids)
        old_to_new[at[held]] = new_global[held]
        moved = np.flatnonzero(old_to_new >= 0)
        points.last_seen[old_to_new[moved]] = old.last_seen[moved]
        points.seen_count[old_to_new[moved]] = old.seen_count[moved]
        points.active[new_track] = old.active[keep]
        self.tracking.replace_map(points, old_to_new, corrected=True)
        self.labels = np.concatenate([update.point_ids.astype(np.uint64), self.labels[keep]])
        self.created = np.concatenate([np.full(len(update.point_ids), self.slot, np.int64),
                                       self.created[keep]])
        self.map_version = update.version


def relabelled(labels: np.ndarray, old: np.ndarray, new: np.ndarray) -> np.ndarray:
    """``labels`` (uint64) with each that equals one of ``old`` replaced by the ``new`` at the
    same place (a repeated old label: its last pair) — the tracks the edge resolved named by
    their map points. One sorted search over the device's ~10 000 labels: a dict lookup a
    label took a quarter of the device's map update in ``bench.edge_work``'s profile, and the
    dict of rows :func:`rows_of_points` replaces two fifths."""
    labels = np.asarray(labels, dtype=np.uint64)
    old, new = np.asarray(old, dtype=np.uint64), np.asarray(new, dtype=np.uint64)
    order = np.argsort(old, kind="stable")
    at, found = find_last(old[order], labels)
    out = labels.copy()
    out[found] = new[order][at[found]]
    return out


def rows_of_points(labels: np.ndarray, point_ids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For each of the map's ``point_ids``, whether ``labels`` hold it as a map point (not a
    track) and at which row (its last); a row is meaningful only where it is held."""
    labels, keys = np.asarray(labels, dtype=np.uint64), np.asarray(point_ids, dtype=np.uint64)
    rows = np.flatnonzero(~is_track(labels))
    order = np.argsort(labels[rows], kind="stable")
    at, found = find_last(labels[rows][order], keys)
    if not len(rows):
        return found, np.zeros(len(keys), dtype=np.int64)
    return found, rows[order][np.where(found, at, 0)]
