"""A place's map at the edge through its life — one device's, or several devices' once their
maps joined (:mod:`~twinslam.slam.back_end.place_joining`): keyframes in, points culled and fused,
keyframes archived and restored, the local bundle adjustment, loops closed (ORB-SLAM's
LocalMapping and LoopClosing in one object; docs/architecture.md §1 step 5).

The edge's slot protocol (``edge_mapper.edge_core``) decides *which* keyframes come and go —
the policy's uploads and evictions, the restores where the camera heads; this object does what
a keyframe's coming and going does to the map, and keeps the map, its archive and the loops
closed so far agreeing with each other:

* :meth:`MapBackEnd.integrate` — a keyframe through the gate
  (:mod:`~twinslam.slam.back_end.keyframe_gate`) into the map
  (:mod:`~twinslam.slam.back_end.local_mapping`, culling the points its view held and never
  found), first moved into the frame the map is in now if a loop corrected it since the
  device posed it (:meth:`DeviceRecord.in_current_frame`);
* :meth:`MapBackEnd.evict_to_archive` and :meth:`MapBackEnd.restore` — keyframes leave for
  the archive and come back from it, the points they bring back fused with their copies
  (:mod:`~twinslam.slam.back_end.point_fusion`);
* :meth:`MapBackEnd.optimise` — the local bundle adjustment, an implausible answer refused;
* :meth:`MapBackEnd.take_loop` and :meth:`MapBackEnd.start_loop_job` — the loop closer's
  answer applied between slots, the next job handed to it
  (:mod:`~twinslam.slam.back_end.loop_closing`);
* :meth:`MapBackEnd.keyframe_trajectory` — every keyframe kept, in the map or the archive, at
  its capture time and where the edge holds it now (ORB-SLAM's keyframe trajectory);
* :meth:`MapBackEnd.checkpoint_arrays` — what a restart needs besides the map's own arrays.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from twinslam.slam.back_end.archive_relocalisation import (
    ArchiveLocation,
    ArchiveRelocalisationConfig,
    locate_in_archive,
)
from twinslam.slam.back_end.bundle_adjustment import (
    BundleAdjustmentResult,
    Observation,
    bundle_adjust,
)
from twinslam.slam.back_end.device_record import DeviceRecord
from twinslam.slam.back_end.foreign_keyframes import (
    copy_anchors,
    is_foreign,
    source_id,
    tag_of,
)
from twinslam.slam.back_end.keyframe_archive import (
    ArchivedKeyFrame,
    KeyFrameArchive,
)
from twinslam.slam.back_end.keyframe_gate import KeyFrameGateConfig, implausible_keyframe
from twinslam.slam.back_end.keyframe_map import KeyFrameMap, shared_pairs
from twinslam.slam.back_end.keyframe_slice import KeyFrameSlice
from twinslam.slam.back_end.keyframe_store import KeyFrameStore
from twinslam.slam.back_end.local_mapping import (
    IntegrationReport,
    LocalMapping,
    LocalMappingConfig,
)
from twinslam.slam.back_end.loop_closing import (
    ACROSS_GAP_SLOTS,
    CONFIRMATIONS,
    LoopCloser,
    LoopJob,
    LoopQuery,
    LoopResult,
)
from twinslam.slam.back_end.loop_correction import (
    correction_for,
    farthest_move,
    move_keyframes,
)
from twinslam.slam.back_end.loop_detection import MIN_GAP
from twinslam.slam.back_end.point_culling import PointCullingConfig
from twinslam.slam.back_end.point_fusion import fuse_restored
from twinslam.slam.back_end.pose_graph import LOOP_INLIERS_REF, LoopEdge, follow_anchors
from twinslam.slam.camera import DEFAULT_IMAGE_SHAPE, Camera
from twinslam.slam.duplicate_points import DUPLICATE_RADIUS_M
from twinslam.slam.keyframe import KeyFramePayload
from twinslam.slot_protocol import default_device
from twinslam.slot_protocol.map_entry import RESTORED, UPLOADED

#: integrated keyframes a loop job looks from at most (the newest)
LOOP_QUERIES = 3
#: a lender's loop that moved no copy this far, or would move no own keyframe this far, is
#: not carried into this map's own keyframes (m): a borrower's own move is a loop its own
#: borrowers follow in turn, and the moves dwindle at each hand-on until they stop here
FOLLOW_MIN_M = 0.002
#: applied loops a map keeps for the maps it lends to (:meth:`MapBackEnd.loops_since`): a
#: borrower follows them at each of its slot ends, a few slots behind at most while it is
#: served
APPLIED_LOOPS_KEPT = 64
#: fusion on integration: a feature lands this close (plus 2 % of its depth) to a point that
#: looks alike, it is that point (the duplicate share's 5 cm)
JOIN_RADIUS_M = DUPLICATE_RADIUS_M


@dataclass(frozen=True)
class BackEndConfig:
    """How the map lives (the edge's parameters of the same names)."""

    #: newest keyframes the local bundle adjustment moves, the rest fixed (0: none)
    ba_window: int = default_device.BA_WINDOW
    ba_iterations: int = 3           #: Gauss–Newton steps (see bundle_adjustment)
    #: points in the local BA at most, most observed first: 120-300 gave the same device ATE
    #: (0.034 m on 600 7-Scenes frames) as all 2-4 k, at 33-70 ms instead of ~200 ms
    ba_points: int | None = 120
    baseline_m: float = 0.08         #: RGB-D virtual stereo baseline of the BA
    image_shape: tuple[int, int] = DEFAULT_IMAGE_SHAPE
    #: evicted keyframes kept for relocalisation and restores (0: none; ~90 kB a keyframe)
    archive_keyframes: int = 500
    #: the points a restored keyframe (or a loop's old place) brings back that the map made
    #: again since are fused into the map's; False: they stay as copies
    point_fusion: bool = True
    #: a map point later keyframes should see and never find leaves the map
    point_culling: bool = False
    #: a new keyframe's feature that would make a point beside a map point that looks alike
    #: observes that point instead (fusion on integration; ``LocalMappingConfig.join_radius_m``)
    integration_fusion: bool = False
    #: the gate on a pose found in the archive for a lost device: inliers after refinement
    reloc_min_inliers: int = 20
    #: the gate every uploaded keyframe passes before it enters the map
    keyframe_gate: KeyFrameGateConfig = field(default_factory=KeyFrameGateConfig)
    #: look for loops from every integrated keyframe and close them with a pose graph
    loop_closing: bool = False
    #: the loop closer's work on a worker thread; False: in the caller (offline pipelines)
    loop_background: bool = True
    #: a loop joins keyframes at least this many ids (frames) apart
    loop_min_gap: int = MIN_GAP
    #: later keyframes that must find a loop's place again before it closes
    loop_confirmations: int = CONFIRMATIONS
    #: in a merged map, a loop may also close with a keyframe of another device of the place
    #: (:attr:`MapBackEnd.loop_across`) that this map adopted ACROSS_GAP_SLOTS before: the
    #: walk bends towards that device's keyframes where it comes to a place the other mapped
    #: first
    loops_across_devices: bool = True


@dataclass(frozen=True)
class ClosedLoop:
    """A loop the edge closed at the end of a slot."""

    old: int                         #: the keyframe of the place seen long before
    new: int                         #: the keyframe that saw it again
    inliers: int                     #: of the geometric check
    moved_m: float                   #: the farthest a managed keyframe moved (or would have)
    #: the loop closer's own time (detection and pose graph), its waits for the slots left out
    worker_ms: float
    #: why its corrections were not applied ("": applied)
    refused: str = ""
    #: the loop closer's waits for the slots' work during the job, ms
    waited_ms: float = 0.0


@dataclass(frozen=True)
class AppliedLoop:
    """A loop a map applied, kept for the maps it lent keyframes to (:meth:`MapBackEnd.follow`)."""

    corrections: dict[int, np.ndarray]   #: own keyframe id → 4×4, in the map's present frame
    #: the move of its own keyframes another map's loop made (:meth:`MapBackEnd.follow`),
    #: not a loop this map closed
    carried: bool = False


@dataclass(frozen=True)
class FollowedLoop:
    """What another device's loop did to this map (:meth:`MapBackEnd.follow`)."""

    copies: int                      #: copies of that device's keyframes moved
    own: int                         #: this map's own keyframes re-posed with them (0: none)
    own_moved_m: float               #: the farthest an own keyframe moved (or would have)
    #: why the own keyframes stayed although tied to the copies ("": they did not)
    refused: str = ""
    graph_ms: float = 0.0            #: the time the own keyframes' graph took (0: none)

    @property
    def reached_own(self) -> bool:
        """Whether the loop moved this map's own keyframes, or would have (refused)."""
        return bool(self.own or self.refused)


class MapBackEnd:
    """The map, its archive and its loops for the devices of one place (see the module's
    text): one device's (:attr:`device`) until another device's map joins it
    (:mod:`~twinslam.slam.back_end.place_joining`, :meth:`add_device`)."""

    def __init__(self, config: BackEndConfig, intrinsics: np.ndarray | None = None,
                 checkpoint: Path | None = None) -> None:
        """A back end for a device of camera ``intrinsics`` (None: taken from its first
        keyframe), restarted from ``checkpoint`` where the file is there."""
        self.config = config
        self.checkpoint = Path(checkpoint) if checkpoint else None
        managed = KeyFrameMap()
        #: the arrays saved beside the map (the edge core reads its own from them)
        self.extra: dict[str, np.ndarray] = {}
        self.restored_from_file = self.checkpoint is not None and self.checkpoint.is_file()
        if self.restored_from_file and self.checkpoint is not None:
            managed, self.extra = KeyFrameMap.load(self.checkpoint)
        extra = self.extra
        #: what the archive could not read back after a restart (the node logs it)
        self.archive_problems: list[str] = []
        #: every keyframe kept: the slice the device holds (:attr:`map`) and the archive
        self.store = KeyFrameStore(managed, self._open_archive(set(managed.keyframes)))
        local_mapping = self._local_mapping(intrinsics)
        #: the device's share of the back end: its slice, tracks, camera, entry order, frames;
        #: in a place of several devices the one that leads it (its core runs the place's
        #: bundle adjustment): the first device's until it hands the place over
        self.device = DeviceRecord.restored(self.store.slice, local_mapping,
                                            config.image_shape, extra)
        #: every device whose keyframes live in :attr:`map`, :attr:`device` first
        self.devices: list[DeviceRecord] = [self.device]
        #: the place's first device, whose keyframes and points carry no tag: its camera
        #: took the keyframes that name none (:meth:`camera_of`), whether it is still served
        #: or handed the place over (:meth:`hand_over`)
        self._first = self.device
        self.loop_closer = LoopCloser(config.loop_background, config.loop_min_gap,
                                      confirmations=config.loop_confirmations)
        #: keyframe → its device's slot it was integrated at, and walk (a device's tag) → its
        #: newest such slot (a place of several devices: which other walks' keyframes are
        #: old enough to close a loop with, :meth:`_across`; each device counts its own
        #: slots)
        self.integrated_at: dict[int, int] = {}
        self._newest_slot: dict[int, int] = {}
        #: walk (its device's tag) → the keyframes it integrated since its last loop job,
        #: newest last
        self._loop_queries: dict[int, list[LoopQuery]] = {}
        #: the walks' loop jobs are started in turn: the walk that started the last one
        self._last_walk = -1
        #: no new loop job starts (an edge over its compute budget); the newest keyframes
        #: integrated meanwhile (LOOP_QUERIES) look once the searches resume
        self.loop_search_paused = False
        #: the tags of the devices whose copies this map's loops may close with (with
        #: ``loops_across_devices``): the other devices of its place, set by whoever merges
        #: the maps (:mod:`edge_mapper.place_merging`)
        self.loop_across: frozenset[int] = frozenset()
        #: copy id → the slot this map adopted it at (:meth:`adopt`): a loop across devices
        #: closes only with a copy adopted ACROSS_GAP_SLOTS before (:meth:`start_loop_job`)
        self.adopted_at: dict[int, int] = dict(zip(
            (int(k) for k in extra.get("adopted_ids", ())),
            (int(s) for s in extra.get("adopted_slots", ())), strict=True))
        self.loops_closed = int(extra.get("loops_closed", 0))
        #: every loop applied: the next loop's graph holds them too (a new loop must not undo
        #: an older one)
        self.loop_edges: list[LoopEdge] = _loop_edges(extra)
        self.loops_refused = 0                 #: loops whose corrections went too far
        #: the newest APPLIED_LOOPS_KEPT loops applied (its own, and the moves of its own
        #: keyframes another device's loop made, :meth:`follow`), each its corrections (own
        #: keyframe id → 4×4) in the map's present frame: what the maps this one lent
        #: keyframes to must apply to their copies (:meth:`loops_since`)
        self.applied_loops: list[AppliedLoop] = []
        #: loops applied before the oldest of :attr:`applied_loops`, no longer kept
        self.loops_forgotten = 0

    def _local_mapping(self, intrinsics: np.ndarray | None) -> LocalMapping:
        """A device's keyframes into :attr:`map` (its camera ``intrinsics``; None: taken from
        its first keyframe)."""
        config = self.config
        return LocalMapping(
            self.map, np.eye(3) if intrinsics is None else intrinsics, config.image_shape,
            LocalMappingConfig(culling=PointCullingConfig() if config.point_culling else None,
                               join_radius_m=JOIN_RADIUS_M if config.integration_fusion
                               else None))

    def add_device(self, tag: int, intrinsics: np.ndarray | None = None,
                   holds: Iterable[int] = (), origin: np.ndarray | None = None
                   ) -> DeviceRecord:
        """Another device into this back end's place: its keyframes enter :attr:`map` under
        ids tagged ``tag`` (:func:`~twinslam.slam.back_end.foreign_keyframes.foreign_tag`),
        its camera ``intrinsics`` (None: taken from its first keyframe), holding the map's
        keyframes ``holds`` at first, its first camera at ``origin`` in the place's frame
        (None: the place's origin; a merge's alignment places it). The place's map,
        archive, bundle adjustment and loops are this back end's; what is the device's alone
        is its record (:class:`~twinslam.slam.back_end.device_record.DeviceRecord`)."""
        if tag == 0 or tag_of(tag) != tag or any(d.tag == tag for d in self.devices):
            raise ValueError(f"{tag} is not a device tag free in this place")
        record = DeviceRecord(self.store.add_slice(holds), self._local_mapping(intrinsics),
                              self.config.image_shape, tag=tag)
        if origin is not None:
            record.origin = np.asarray(origin, dtype=np.float64).reshape(4, 4).copy()
        self.devices.append(record)
        return record

    def hand_over(self, to: DeviceRecord, slot: int) -> list[int]:
        """The device that leads the place (:attr:`device`: its core runs the place's
        bundle adjustment) gone: ``to``, another device of the place, leads it from now on.
        The keyframes the one gone held that no other device holds leave the map for the
        archive at ``slot``, as :meth:`remove_device` sends a joined device's; its record
        and slice go. Its keyframes keep its camera (:meth:`camera_of`) and their ids. The
        archived keyframes the archive forgot to make room (its capacity)."""
        if to is self.device or to not in self.devices:
            raise ValueError("a place is handed over to another device of it")
        forgotten = self._drop_device(self.device, slot)
        self.store.slice, self.device = to.slice, to
        return forgotten

    def remove_device(self, record: DeviceRecord, slot: int) -> list[int]:
        """A device of the place other than the one leading it gone (reclaimed, failed, started
        again): the keyframes it held that no other device holds leave the map for the
        archive at ``slot`` — the place keeps them, restores bring them back where a device
        heads — and its record and slice go. The archived keyframes the archive forgot to
        make room (its capacity)."""
        if record is self.device or record not in self.devices:
            raise ValueError("only a device that joined this place can leave it (its "
                             "leading device hands it over)")
        return self._drop_device(record, slot)

    def _drop_device(self, record: DeviceRecord, slot: int) -> list[int]:
        """``record``'s device gone: the keyframes only it held to the archive at ``slot``,
        its record and slice out of the place; the archived keyframes forgotten for room."""
        forgotten, _ = self.evict_to_archive(list(record.slice.keyframes), slot, record)
        self.devices.remove(record)
        self.store.slices.remove(record.slice)
        return forgotten

    def newest_slots(self) -> dict[int, int]:
        """Each walk's (its device's tag's) newest slot a keyframe of it was integrated at,
        that device's own slot."""
        return dict(self._newest_slot)

    def carry_integration_slots(self, integrated_at: Mapping[int, int],
                                newest: Mapping[int, int]) -> None:
        """The slots a joining map's keyframes were integrated at (``integrated_at``, by
        their ids here) and its walks' newest (``newest``, by their tags here): its walks
        go on here, and which of their keyframes another walk's loop may close with is
        counted by their own devices' slots as before (:meth:`_across`)."""
        self.integrated_at.update(integrated_at)
        for walk, slot in newest.items():
            self._newest_slot[walk] = max(slot, self._newest_slot.get(walk, -1))

    @property
    def map(self) -> KeyFrameMap:
        """The managed map: the store's slice, the keyframes the device holds."""
        return self.store.managed

    @property
    def slice(self) -> KeyFrameSlice:
        """The keyframes the device holds of :attr:`map`: what its map update, uncertainty,
        policy and evictions read (the whole map while the map is one device's)."""
        return self.device.slice

    @property
    def archive(self) -> KeyFrameArchive:
        """The store's keyframes out of the slice."""
        return self.store.archive

    def _open_archive(self, in_map: set[int]) -> KeyFrameArchive:
        """The archive beside the checkpoint (``edge.npz`` → ``edge.npz.archive/``), restored
        with the map (whose keyframes are ``in_map``); a fresh start (no map checkpoint)
        clears what an earlier run left there, whose keyframe ids a new device run would
        reuse."""
        capacity = self.config.archive_keyframes
        if self.checkpoint is None:
            return KeyFrameArchive(capacity)
        folder = archive_folder(self.checkpoint)
        if self.restored_from_file:
            archive, self.archive_problems = KeyFrameArchive.restore(capacity, folder, in_map)
            return archive
        for stale in folder.glob("keyframe-*.npz*") if folder.is_dir() else ():
            stale.unlink()                    # its files, and any an owed write left staged
        return KeyFrameArchive(capacity, folder)

    def set_bundle_adjustment(self, window: int, points: int | None) -> None:
        """The local bundle adjustment from the next slot on: ``window`` newest keyframes (0:
        none), at most ``points`` points."""
        self.config = dataclasses.replace(self.config, ba_window=max(0, int(window)),
                                          ba_points=points)

    @property
    def camera(self) -> Camera:
        """The camera of the place's own keyframes, those that name none (its first
        device's, served or not): its intrinsics (the identity until the first keyframe
        brings them) and the configured image size."""
        return self._first.camera

    @property
    def k(self) -> np.ndarray:
        """The intrinsics of :attr:`camera` (:attr:`DeviceRecord.k`)."""
        return self._first.k

    # -- keyframes in ------------------------------------------------------------------------

    def camera_of(self, kf_id: int) -> Camera:
        """The camera that took keyframe ``kf_id`` of the map: the device's, or — another
        device's keyframe (a copy) — its own intrinsics at the configured image size."""
        own = self.map.keyframes[kf_id].intrinsics
        return self.camera if own is None else Camera(own, self.config.image_shape)

    def integrate(self, data: KeyFramePayload, tracked_on: int,
                  device: DeviceRecord | None = None) -> IntegrationReport:
        """A keyframe the device (default :attr:`device`) posed on its map version
        ``tracked_on`` (-1: unknown) into the map, moved into the map's frame now, if the gate
        lets it; a refusal changes nothing (its report says why). Its id is the place's: a
        device other than the first names its keyframes under its tag."""
        device = device or self.device
        data = device.in_current_frame(data, tracked_on)
        # the gate reaches from the keyframe nearest in ids: a tagged device's first camera
        # is its tag's frame 0
        first = [(device.tag, device.origin)] if device.tag else []
        refused = implausible_keyframe(data, self.map,
                                       [*first, *((kf.id, kf.pose) for kf in self.archive)],
                                       self.config.keyframe_gate, device.origin)
        if refused:
            return IntegrationReport.refusal(refused)
        device.k = data.intrinsics
        report = device.local_mapping.integrate(data.frame_id, data.pose, data.keypoints,
                                                data.descriptors, data.depths, data.point_ids)
        if data.frame_id in self.map.keyframes:
            if device.tag:                    # the place's first device's camera is the map's
                self.map.keyframes[data.frame_id].intrinsics = device.k.copy()
            self.store.entered([data.frame_id], device.slice)   # the device's, no other's
            device.entered[data.frame_id] = (int(data.slot), UPLOADED)
            device.keyframe_stamps[data.frame_id] = float(data.stamp)
            self.integrated_at[data.frame_id] = int(data.slot)
            self._newest_slot[device.tag] = max(int(data.slot),
                                                self._newest_slot.get(device.tag, -1))
            # each device's keyframes are steps of its own walk: a loop closes within it
            if self.config.loop_closing:
                queued = self._loop_queries.get(device.tag, [])
                self._loop_queries[device.tag] = [*queued[-(LOOP_QUERIES - 1):],
                                                  LoopQuery.of(data)]
        return report

    # -- keyframes out and back --------------------------------------------------------------

    def evict_to_archive(self, keyframes: Iterable[int], slot: int,
                         device: DeviceRecord | None = None) -> tuple[list[int], int]:
        """``keyframes`` evicted by the device (default :attr:`device`) at ``slot``: into the
        archive, but those another device of the place still holds, which stay in the map;
        (the archived keyframes that left the archive to keep its capacity, the points that
        lost their last observer)."""
        device = device or self.device
        keyframes = list(keyframes)
        forgotten, orphans = self.store.leave_slice(keyframes, slot, device.slice)
        for kf in keyframes:
            device.entered.pop(kf, None)
        for kf in forgotten:
            self.adopted_at.pop(kf, None)
            self.integrated_at.pop(kf, None)
        return forgotten, orphans

    def restore(self, restore: Iterable[int], evict: Iterable[int], slot: int,
                device: DeviceRecord | None = None) -> tuple[list[int], int]:
        """Keyframes ``restore`` brought into the slice of the device (default
        :attr:`device`) in place of ``evict`` (which leave it in their turn): archived ones
        back into the map, and — in a place of several devices — ones another device holds
        in the map, as they are (their points are the place's); (forgotten by the archive to
        make room, points fused: the points an archived keyframe brings back that the map
        made again since)."""
        device = device or self.device
        restore = list(restore)
        in_place = [kf for kf in restore if kf in self.map.keyframes]
        back = [self.archive.take(kf) for kf in restore if kf not in self.map.keyframes]
        forgotten, _ = self.evict_to_archive(evict, slot, device)
        returned = self.store.enter_slice(back, device.slice)
        taken = self.store.take_from_place(in_place, device.slice)
        device.entered.update((kf, (slot, RESTORED)) for kf in [*returned, *taken])
        fused = sum(len(fuse_restored(self.map, kf, points, self.camera_of(kf)))
                    for kf, points in returned.items()) if self.config.point_fusion else 0
        return forgotten, fused

    def relocalise(self, points_xy: np.ndarray, descriptors: np.ndarray, slot: int,
                   device: DeviceRecord | None = None) -> ArchiveLocation:
        """A lost device's (default :attr:`device`) frame — its ORB keypoints and descriptors —
        found in the archive; the recognised keyframes count as useful at ``slot``."""
        found = locate_in_archive(self.archive, points_xy, descriptors,
                                  (device or self.device).k,
                                  ArchiveRelocalisationConfig(
                                      min_inliers=self.config.reloc_min_inliers))
        if found.pose is not None:
            self.archive.touch(list(found.keyframes), slot)
        return found

    # -- optimisation ------------------------------------------------------------------------

    def optimise(self) -> BundleAdjustmentResult | None:
        """Local BA: the newest ``ba_window`` keyframes by id and the points they share with
        another keyframe move; the other keyframes that see those points hold still (and the
        oldest always does). In a merged map another device's keyframes (copies) carry tagged
        ids above every own one, so the window is the newest copies and the map's own
        keyframes hold still: measured better than the other way round (the map's own newest
        keyframes moving against copies held where their lender has them: the borrower's ATE
        +11 cm live with the paper's preset, the two maps' keyframes +1.8 cm further apart in
        process; docs/results/shared-map.md, "Which keyframes a merged map adjusts"). A point
        only one keyframe sees constrains no pose: it moves rigidly with its keyframe instead
        of entering the graph. Observations the optimiser finds to be outliers are removed
        from the map (ORB-SLAM's local BA does the same). An answer
        :meth:`_implausible_adjustment` refuses changes nothing (its ``refused`` says why)."""
        if len(self.map.keyframes) < 2 or self.config.ba_window <= 0:
            return None
        ids = self.map.keyframe_ids()
        window = set(ids[-self.config.ba_window:]) - {ids[0]}
        if not window:
            return None
        seen = set().union(*(self.map.keyframes[k].points for k in window))
        points = seen_twice = {p for p in seen if len(self.map.points[p].observers) >= 2}
        cap = self.config.ba_points
        if cap is not None and len(points) > cap:
            # the best-observed points constrain the poses most; the rest hold still
            ranked = sorted(points, key=lambda p: (-len(self.map.points[p].observers), p))
            points = set(ranked[:cap])
        observers = set().union(*(self.map.points[p].observers for p in points)) | window
        observations = []
        for kf in observers:
            meas = self.map.keyframes[kf].measurements
            for p in points & self.map.keyframes[kf].points:
                u, v, d = meas.get(p, (math.nan, math.nan, math.nan))
                if math.isfinite(u) and math.isfinite(v):
                    observations.append(Observation(kf, p, (u, v), d))
        fixed = observers - window
        if not observations or not fixed:
            return None
        # another device's keyframes (copies) were taken by its camera, not this device's
        cameras = {k: c for k in observers if (c := self.map.keyframes[k].intrinsics) is not None}
        result = bundle_adjust({k: self.map.keyframes[k].pose for k in observers},
                               {p: self.map.points[p].position for p in points}, observations,
                               self.k, fixed, baseline_m=self.config.baseline_m,
                               max_iterations=self.config.ba_iterations, cameras=cameras)
        refused = self._implausible_adjustment(result, window)
        if refused:
            return dataclasses.replace(result, refused=refused)
        for k in window:
            keyframe = self.map.keyframes[k]
            motion = result.poses[k] @ np.linalg.inv(keyframe.pose)
            for p in keyframe.points - seen_twice:      # single-observer points ride along
                pt = self.map.points[p]
                pt.position = motion[:3, :3] @ pt.position + motion[:3, 3]
            keyframe.pose = result.poses[k]
        for p in points:
            self.map.points[p].position = result.points[p]
        for ob in result.outliers:
            if ob.point in self.map.points:
                self.map.unobserve(ob.keyframe, ob.point)
        return result

    def _implausible_adjustment(self, result: BundleAdjustmentResult, window: set[int]) -> str:
        """Why the adjustment's answer must not be applied, or "": a non-finite pose or point
        (a diverged solve), an error larger than it started from (Gauss–Newton takes its
        steps whatever they do to the error: on the synthetic corridor one raised it from
        1.2e3 to 1.0e6 and turned a keyframe 115°, bench.map_consistency), or a keyframe
        moved farther than a device accepts on a map swap (:meth:`_beyond_reach`): a local
        adjustment with its neighbours held still has no reason to move one so far."""
        if not all(np.isfinite(result.poses[k]).all() for k in window) or \
                not all(np.isfinite(p).all() for p in result.points.values()):
            return "a non-finite pose or point"
        if not result.final_error <= result.initial_error:
            return (f"the adjustment raised its error from {result.initial_error:.3g} to "
                    f"{result.final_error:.3g}")
        for k in sorted(window):
            moved = _moved_m(self.map.keyframes[k].pose, result.poses[k])
            if refused := self._beyond_reach(f"keyframe {k} moved", moved):
                return refused
        return ""

    def _beyond_reach(self, what: str, moved_m: float) -> str:
        """Why a map that moves ``moved_m`` under the device is refused (``what`` moved that
        far), or "": farther than the correction a device accepts on a map swap
        (``MotionBounds.correction_m``; its tracking would refuse every pose on that map)."""
        reach = self.config.keyframe_gate.motion.correction_m
        return f"{what} {moved_m:.3g} m, more than {reach:g} m" if moved_m > reach else ""

    # -- loop closing ------------------------------------------------------------------------

    def start_loop_job(self, slot: int) -> None:
        """Hand the keyframes a walk integrated since its last job to the loop closer, with
        a snapshot of the archive, the map's keyframes far older than them and every pose;
        kept for the next slot while a job runs or the searches are paused
        (:attr:`loop_search_paused`). Each device of the place walks a walk of its own (its
        keyframes, under its tag): the walks with keyframes waiting start their jobs in
        turn, one job at a time for the place — a job's graph holds the other walks where
        they are, and two at once would each hold the other where it no longer is."""
        if self.loop_search_paused:
            return
        walks = {device.tag: device for device in self.devices}
        for tag in [tag for tag in self._loop_queries if tag not in walks]:
            del self._loop_queries[tag]                   # a device that left the place
        for tag, queued in self._loop_queries.items():
            in_map = [q for q in queued if q.keyframe in self.map.keyframes]
            wanted = set(self.loop_closer.wanted([q.keyframe for q in in_map]))
            self._loop_queries[tag] = [q for q in in_map if q.keyframe in wanted]
        ready = sorted(tag for tag, queued in self._loop_queries.items()
                       if queued and walks[tag].camera.known)
        if not ready or self.loop_closer.busy:
            return
        walk = next((tag for tag in ready if tag > self._last_walk), ready[0])
        queries = self._loop_queries[walk]
        newest = max(q.keyframe for q in queries)
        # the walk's own keyframes: another walk's, and another device's this map adopted,
        # are no step of it, but anchors its keyframes posed on them hold to (LoopJob.copies)
        every = self.keyframe_poses()
        across = self._across(every, slot, walk)
        # the walk's old keyframes in the map, and the copies a loop may close with across
        # devices that are in the map (the archive's are in its snapshot already)
        old = [ArchivedKeyFrame.of(self.map, k, slot) for k in self.map.keyframes
               if (tag_of(k) == walk and k <= newest - self.loop_closer.min_gap)
               or k in across]
        poses = {k: pose for k, pose in every.items() if tag_of(k) == walk}
        job = LoopJob(tuple(reversed(queries)), self.archive.snapshot(old), poses,
                      walks[walk].k.copy(),
                      {k: frozenset(kf.points) for k, kf in self.map.keyframes.items()
                       if tag_of(k) == walk},
                      tuple(self.loop_edges),
                      {k: pose for k, pose in every.items() if tag_of(k) != walk},
                      {k: frozenset(kf.points) for k, kf in self.map.keyframes.items()
                       if tag_of(k) != walk}, across, walk)
        if self.loop_closer.submit(job):
            self._loop_queries[walk] = []
            self._last_walk = walk

    def _across(self, poses: Mapping[int, np.ndarray], slot: int, walk: int = 0
                ) -> frozenset[int]:
        """The keyframes of other devices (of ``poses``: every keyframe's) a loop of walk
        ``walk`` may close with at ``slot``, with ``loops_across_devices``: in a place of
        several devices, the other walks' keyframes integrated ACROSS_GAP_SLOTS or more of
        their own device's slots before its newest (devices count slots from their own
        starts; a joined map's keyframes keep the slots they were integrated at,
        :meth:`carry_integration_slots`); in a map of one device,
        the copies of the devices of :attr:`loop_across` adopted ACROSS_GAP_SLOTS before
        ``slot`` or earlier (one adopted before the edge kept adoption slots counts as old).
        A place where the other
        device was at the same time as this one — the two walks crossing — bends neither
        towards the other: each would bend towards a keyframe the other is moving at once;
        the later comer bends, as a loop of one walk bends its newer end towards its older."""
        if not self.config.loops_across_devices:
            return frozenset()
        if len(self.devices) > 1:
            newest = self._newest_slot
            return frozenset(
                k for k in poses if tag_of(k) != walk and (
                    (at := self.integrated_at.get(k)) is None
                    or at <= newest.get(tag_of(k), at) - ACROSS_GAP_SLOTS))
        if not self.loop_across:
            return frozenset()
        latest = slot - ACROSS_GAP_SLOTS
        return frozenset(k for k in poses if is_foreign(k) and tag_of(k) in self.loop_across
                         and self.adopted_at.get(k, latest) <= latest)

    def take_loop(self) -> ClosedLoop | None:
        """The loop closer's finished job applied (None: none finished, or it found no loop),
        its corrections in each device's next map version."""
        return self._apply_loop(self.loop_closer.take())

    def _apply_loop(self, result: LoopResult | None) -> ClosedLoop | None:
        """A finished loop job's corrections, applied to the managed map and the archive
        (between slots: the map the device gets next is corrected); the old place, where it is
        in the map, has its points fused with the ones the walk made again. A loop that would
        move a keyframe of the map farther than a device accepts on a map swap
        (:meth:`_beyond_reach`) is refused, as the bundle adjustment's answer would be: a
        place that only looked alike."""
        if result is not None and result.error:
            return ClosedLoop(-1, result.query, 0, 0.0, result.seconds * 1e3,
                              f"the loop closer failed: {result.error}",
                              result.waited * 1e3)
        if result is None or result.closure is None:
            return None
        corrections = result.closure.corrections
        farthest = farthest_move(self.map, corrections, result.walk)
        if refused := self._beyond_reach("it would move the map", farthest):
            self.loops_refused += 1
            return ClosedLoop(result.candidate.old, result.query, result.candidate.inliers,
                              farthest, result.seconds * 1e3, refused, result.waited * 1e3)
        # the walk's head (the newest keyframe of the graph, and every later one) moves by the
        # newest correction: the frame the next map version is in
        self._correct(corrections, "writing the loop-corrected archive's poses", walk=result.walk)
        old = result.candidate.old
        if self.config.point_fusion and old in self.map.keyframes and self.camera.known:
            fuse_restored(self.map, old, sorted(self.map.keyframes[old].points),
                          self.camera_of(old))
        self.loops_closed += 1
        self._keep_applied(AppliedLoop(dict(corrections)))
        if result.candidate.measured is not None:
            self.loop_edges.append(LoopEdge(old, result.query, result.candidate.measured,
                                            result.candidate.inliers))
        return ClosedLoop(old, result.query, result.candidate.inliers, farthest,
                          result.seconds * 1e3, waited_ms=result.waited * 1e3)

    def _correct(self, corrections: Mapping[int, np.ndarray], what: str,
                 everywhere: np.ndarray | None = None, walk: int = 0) -> None:
        """Move the map's and the archive's keyframes by their ``corrections`` (points with
        their reference keyframes), and the frame the map is in for each device — from its
        next map version on — by the correction at its walk's head
        (:meth:`DeviceRecord.head_of`), which every pose it holds and every keyframe it is
        about to upload still needs; a device none of whose keyframes moved keeps its frame. A
        loop's corrections reach its walk's keyframes alone (``walk``, a device's tag;
        :func:`correction_for`: the other walks, and the copies the map adopted, hold where
        they are); with ``everywhere`` (a rigid motion) the whole
        map changes frame: each keyframe ``corrections`` names moves, copies included, and
        every device's frame by ``everywhere``. The archive's pose file is written beside the
        slots (``what`` it is, for a failure)."""
        def of(kf_id: int) -> np.ndarray | None:
            return corrections.get(kf_id) if everywhere is not None \
                else correction_for(corrections, kf_id, walk)

        move_keyframes(self.map, {k: c for k in self.map.keyframes if (c := of(k)) is not None})
        for device in self.devices:
            head = everywhere if everywhere is not None else device.head_of(corrections)
            if head is not None:
                device.frame_moved(head)
        archived = self.archive.correct(
            {kf.id: c for kf in self.archive if (c := of(kf.id)) is not None}, write=False)
        if archived:
            self.loop_closer.after(self.archive.save_poses, what)

    def align(self, alignment: np.ndarray) -> None:
        """Move the whole map — every keyframe, the map's and the archive's, and every point —
        by the rigid motion ``alignment`` into another frame (the frame of a place another
        device mapped first, :mod:`twinslam.slam.back_end.map_merging`), from each device's
        next map version on. To the device it is a loop's correction that moved every
        keyframe alike: its next map update carries the new ``frame_correction`` and the
        device moves what it holds with it. A loop job running on the poses before is
        dropped: its corrections belong to the frame the map left."""
        alignment = checked_alignment(alignment)
        self.loop_closer.discard()
        for device in self.devices:
            device.origin = alignment @ device.origin
        # a loop's correction c moves points of the old frame; in the new one it is A c A⁻¹
        undo = np.linalg.inv(alignment)
        self.applied_loops = [dataclasses.replace(loop, corrections={
            k: alignment @ c @ undo for k, c in loop.corrections.items()})
            for loop in self.applied_loops]
        # the copies of other devices' keyframes too: they are in this map's frame, and a
        # copy left behind is a whole merge's motion away from the place it shows
        everyone = dict.fromkeys(self.store.ids(), alignment)
        self._correct(everyone, "writing the aligned archive's poses", everywhere=alignment)

    def follow(self, loop: AppliedLoop, tag: int) -> FollowedLoop:
        """Another device's loop, applied to the copies of its keyframes this map adopted
        (ids tagged ``tag``; ``loop.corrections`` by the lender's own ids, in this map's
        frame — the place's), and — a loop the lender closed, not one it carried from
        another map — to this map's own keyframes tied to the copies, from the device's next
        map version on.

        Each copy moves as its original did (one newer than the lender's graph as the
        lender's head, :func:`~twinslam.slam.back_end.loop_correction.correction_for`), and
        with it every point only copies observe. Without it, copies lent before the lender's
        loop keep its drift while those lent after carry the correction, a loop's
        correction apart, and a device tracking on the first cannot match the second
        (docs/results/shared-map.md). Then this map's own keyframes — posed where the device
        tracked on the copies' points, and the walk chained to them — are re-posed where the
        moved copies hold them (:func:`~twinslam.slam.back_end.pose_graph.follow_anchors`:
        one loop's correction for the place, not only for the lender's keyframes), their
        points with them and the map's frame by its head's correction, as after a loop of
        its own: its device moves what it holds with the next map update. A move beyond a
        device's reach is refused (the copies still follow). Only the keyframes the device
        posed on the copies are tied to them — by the points a copy brought, to the copy that
        brought them (:func:`~twinslam.slam.back_end.foreign_keyframes.ties_to_copies`), not
        by those a copy was welded to: this map's keyframes made before the copies came (the
        place's first map, say) did not inherit the lender's drift, and a lender's loop that
        takes it out must not move them.

        A move carried so is kept as a loop too (``carried``): the maps this one lent to move
        their copies of its keyframes by it, but never carry it into their own keyframes
        again — a lender that carried a borrower's move back would echo it: each move,
        measured against the relation the two maps had before the other moved, would call
        for the same move again (measured: both maps moving 10 cm back and forth, slot after
        slot, docs/results/shared-map.md)."""
        def of(copy: int) -> np.ndarray | None:
            return correction_for(loop.corrections, source_id(copy)) \
                if tag_of(copy) == tag else None

        copies_before = {k: pose for k, pose in self.keyframe_poses().items()
                         if is_foreign(k)}
        archived = self.archive.correct(
            {kf.id: c for kf in self.archive if (c := of(kf.id)) is not None}, write=False)
        if archived:
            self.loop_closer.after(self.archive.save_poses,
                                   "writing the archive's poses after a lender's loop")
        moved = {k: c for k in self.map.keyframes if (c := of(k)) is not None}
        if moved:
            move_keyframes(self.map, moved)
        copies_moved = len(archived) + len(moved)
        poses = self.keyframe_poses()
        farthest_copy = max((_moved_m(before, pose) for k, pose in poses.items()
                             if (before := copies_before.get(k)) is not None), default=0.0)
        if loop.carried or farthest_copy < FOLLOW_MIN_M:
            return FollowedLoop(copies_moved, 0, 0.0)
        return self._carry_own(poses, copies_before, copies_moved)

    def _carry_own(self, poses: Mapping[int, np.ndarray],
                   copies_before: Mapping[int, np.ndarray], copies_moved: int
                   ) -> FollowedLoop:
        """This map's own keyframes (``poses``: every keyframe's, the copies moved) re-posed
        where the copies that moved from ``copies_before`` hold them (:meth:`follow`)."""
        started = time.perf_counter()
        own = {k: pose for k, pose in poses.items() if not is_foreign(k)}
        copies_now = {k: pose for k, pose in poses.items() if is_foreign(k)}
        points = self.store.point_sets()
        closure = follow_anchors(own, copy_anchors(points, copies_before, copies_now),
                                 shared_pairs(list(own), points), self.loop_edges)
        graph_ms = (time.perf_counter() - started) * 1e3
        if closure is None:
            return FollowedLoop(copies_moved, 0, 0.0, graph_ms=graph_ms)
        farthest = max(_moved_m(own[k], closure.poses[k]) for k in own)
        if farthest < FOLLOW_MIN_M:
            return FollowedLoop(copies_moved, 0, farthest, graph_ms=graph_ms)
        if refused := self._beyond_reach("following it would move the map", farthest):
            self.loops_refused += 1
            return FollowedLoop(copies_moved, 0, farthest, refused, graph_ms)
        corrections = closure.corrections
        self._correct(corrections, "writing the archive's poses after following a lender's loop")
        # the maps this one lent its keyframes to move their copies of them in turn
        self._keep_applied(AppliedLoop(dict(corrections), carried=True))
        return FollowedLoop(copies_moved, len(corrections), farthest, graph_ms=graph_ms)

    def _keep_applied(self, loop: AppliedLoop) -> None:
        """A loop kept for the maps this one lends to; the oldest forgotten beyond
        APPLIED_LOOPS_KEPT (each holds a 4×4 a keyframe: an edge that runs for days must not
        keep every loop it ever closed)."""
        self.applied_loops.append(loop)
        if len(self.applied_loops) > APPLIED_LOOPS_KEPT:
            del self.applied_loops[0]
            self.loops_forgotten += 1

    @property
    def loops_applied(self) -> int:
        """Every loop applied since the edge started, the forgotten ones too."""
        return self.loops_forgotten + len(self.applied_loops)

    def loops_since(self, count: int) -> list[AppliedLoop]:
        """The loops applied after the first ``count`` (:attr:`loops_applied` counts them),
        as far as they are still kept."""
        return self.applied_loops[max(0, count - self.loops_forgotten):]

    def adopt(self, keyframes: Iterable[ArchivedKeyFrame]) -> list[int]:
        """Another device's keyframes, in this map's frame and under their tagged ids
        (:func:`~twinslam.slam.back_end.map_merging.welded`), into the archive: restores
        bring them into the map where this device heads, as its own archived keyframes, and
        the device tracks on them. Those the archive holds already are skipped; returns the
        archived keyframes that left to make room."""
        added, forgotten = self.archive_keyframes(keyframes,
                                                  "writing the adopted keyframes' files")
        self.adopted_at.update((kf.id, kf.archived_slot) for kf in added)
        for kf_id in forgotten:
            self.adopted_at.pop(kf_id, None)
        return forgotten

    def archive_keyframes(self, keyframes: Iterable[ArchivedKeyFrame], what: str
                          ) -> tuple[list[ArchivedKeyFrame], list[int]]:
        """Keyframes from elsewhere (another device's, in this map's frame and under their
        tagged ids) into the archive, but those the store holds already, their files written
        beside the slots (``what`` they are, for a failure: a merge brings hundreds at
        once); (the keyframes archived, the archived keyframes that left to make room)."""
        forgotten: list[int] = []
        added: list[ArchivedKeyFrame] = []
        for kf in keyframes:
            if kf.id not in self.store:
                forgotten += self.archive.add(kf, write=False)
                added.append(kf)
        if added:
            ids = [kf.id for kf in added]
            self.loop_closer.after(lambda: self.archive.save(ids), what)
        return added, forgotten

    def release_copies(self, copies: Iterable[int]) -> dict[int, int]:
        """Other devices' keyframes this map adopted (tagged ids) taken out of its archive
        for good: its device no longer comes where they are, and their lenders keep the
        originals, to lend again where it does (:func:`~twinslam.slam.back_end.map_merging.
        lend_from`). Copies in the managed map, or not held, stay. Each released copy's
        adoption slot (0 where the map did not record it: counted as old, as
        :meth:`_across` counts it), by its tagged id."""
        released: dict[int, int] = {}
        for copy in copies:
            if is_foreign(copy) and copy in self.archive:
                self.archive.drop(copy)
                released[copy] = self.adopted_at.pop(copy, 0)
        return released

    def close(self) -> None:
        """Stop the loop closer's worker (the node calls it at shutdown)."""
        self.loop_closer.close()

    def keyframe_trajectory(self, device: DeviceRecord | None = None
                            ) -> list[tuple[float, np.ndarray]]:
        """(capture time in s, camera-to-map pose) of every keyframe the device (default
        :attr:`device`) uploaded that is kept — in the map or the archive — oldest first, each
        where the edge holds it now: its walk as one trajectory, which its map updates never
        carry (an archived keyframe a loop corrects is not sent again). Keyframes of unknown
        capture time (a checkpoint written before they were kept) are left out."""
        stamps = (device or self.device).keyframe_stamps
        return sorted(((stamps[k], pose.copy()) for k, pose in self.keyframe_poses().items()
                       if k in stamps), key=lambda entry: entry[0])

    def keyframe_poses(self) -> dict[int, np.ndarray]:
        """Every keyframe kept — the archive's and the map's — by id, where the edge holds it
        now (the map's as copies: another thread may read them while the map moves on)."""
        return self.store.poses()

    # -- checkpoint --------------------------------------------------------------------------

    def checkpoint_arrays(self) -> dict[str, np.ndarray]:
        """What a restarted back end reads back besides the map: the loops applied, the
        frame they left the map in, where a merge put the device's first camera and the
        capture times of the keyframes kept."""
        return {"loops_closed": np.array(self.loops_closed), **_loop_arrays(self.loop_edges),
                **self.device.checkpoint_arrays(self.store),
                **_adopted_arrays({k: s for k, s in self.adopted_at.items()
                                   if k in self.store})}


def _moved_m(before: np.ndarray, after: np.ndarray) -> float:
    """How far a pose's camera moved (m)."""
    return float(np.linalg.norm(after[:3, 3] - before[:3, 3]))


def checked_alignment(alignment: np.ndarray) -> np.ndarray:
    """``alignment`` as a float 4×4 — the rigid motion that moves one map into another's
    frame — or ValueError where it is not a finite 4×4 (nothing moves on a broken one)."""
    checked = np.asarray(alignment, dtype=np.float64)
    if checked.shape != (4, 4) or not np.isfinite(checked).all():
        raise ValueError("an alignment is a finite 4×4 rigid motion")
    return checked


def archive_folder(checkpoint: Path) -> Path:
    """Where the archive of the map checkpointed at ``checkpoint`` lives."""
    return checkpoint.with_name(checkpoint.name + ".archive")


def _adopted_arrays(adopted: Mapping[int, int]) -> dict[str, np.ndarray]:
    """The slots the map's copies were adopted at, as the checkpoint's two arrays."""
    ids = sorted(adopted)
    return {"adopted_ids": np.array(ids, dtype=np.int64),
            "adopted_slots": np.array([adopted[k] for k in ids], dtype=np.int64)}


def _loop_arrays(edges: list[LoopEdge]) -> dict[str, np.ndarray]:
    """The loops applied as the checkpoint's arrays."""
    return {"loop_old": np.array([e.old for e in edges], dtype=np.int64),
            "loop_new": np.array([e.new for e in edges], dtype=np.int64),
            "loop_measured": np.array([e.measured for e in edges],
                                      dtype=np.float64).reshape(-1, 4, 4),
            "loop_inliers": np.array([e.inliers for e in edges], dtype=np.int64)}


def _loop_edges(extra: dict[str, np.ndarray]) -> list[LoopEdge]:
    """The loops :func:`_loop_arrays` wrote (none in a checkpoint written before them; one
    written before loops kept their inliers: each as stiff as LOOP_INLIERS_REF's)."""
    measured = np.asarray(extra.get("loop_measured", np.zeros((0, 4, 4)))).reshape(-1, 4, 4)
    inliers = extra.get("loop_inliers", np.full(len(measured), LOOP_INLIERS_REF))
    return [LoopEdge(int(o), int(n), m, int(i)) for o, n, m, i in
            zip(extra.get("loop_old", []), extra.get("loop_new", []), measured, inliers,
                strict=True)]
