"""The edge's work for one device, slot by slot, without DDS (docs/architecture.md §1 steps 3, 5,
6).

``plan`` answers a slot's frame summaries with U_k and C_k (and υ of those frames against the
map, the previous decision's reward); ``add_keyframe`` integrates each uploaded keyframe the
plan asked for; ``finish_slot`` evicts C_k (less what uploads that never came would have
needed: the map never shrinks for lack of uploads), restores archived keyframes where the
camera heads, applies a finished loop, bumps the map version and writes the checkpoint. What
each of those does to the map — integration, culling, fusion, the archive, the local bundle
adjustment, loops — is the back end's
(:class:`~twinslam.slam.back_end.map_back_end.MapBackEnd`); this class orchestrates the slots
around it: which keyframes, when. An evicted keyframe leaves the managed map (V_max: what is
sent to the device) for the edge's archive, which keeps it up to ``archive_keyframes``. The
node (``edge_mapper/node.py``) only moves messages in and out of this class; a restarted node
resumes from the checkpoint.

Slots may overlap: a slot shorter than its uploads take (D_req) is planned while the one
before still waits for keyframes. The map then never holds more than V_max keyframes when a
slot finishes, because (1) a plan is sized against the map the open slots will leave — their
uploads counted in, their evictions out (``SlotPlanner.plan``'s ``arriving``/``leaving``);
(2) slots finish in order (``oldest_open``); (3) a keyframe of a later slot is held, not
integrated, while an earlier slot is open (``integrate_held`` after that slot finished); and
(4) a keyframe of a finished slot is not integrated any more.
"""

from __future__ import annotations

import copy
import dataclasses
import math
import time
from collections.abc import Callable, Collection, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from edge_mapper.checkpoint_writer import CheckpointWriter
from edge_mapper.place_ids import PlaceIds, PlaceJoin
from edge_mapper.planning_world import at_the_edge, extrapolate
from edge_mapper.restores import (
    MIN_VISIBLE,
    plan_relocation_restores,
    plan_restores,
    view_scores,
)
from edge_mapper.slot_planner import FrameObservations, SlotConfig, SlotPlan, SlotPlanner
from twinslam.policies.actions import MapAction
from twinslam.policies.protocol import MapPolicy
from twinslam.slam.back_end.archive_relocalisation import ArchiveLocation
from twinslam.slam.back_end.bundle_adjustment import BundleAdjustmentResult
from twinslam.slam.back_end.device_record import DeviceRecord
from twinslam.slam.back_end.keyframe_archive import ArchivedKeyFrame, KeyFrameArchive
from twinslam.slam.back_end.keyframe_map import KeyFrameMap, write_checkpoint
from twinslam.slam.back_end.keyframe_slice import KeyFrameSlice
from twinslam.slam.back_end.local_mapping import IntegrationReport, LocalMapping
from twinslam.slam.back_end.loop_closing import LoopCloser
from twinslam.slam.back_end.map_back_end import BackEndConfig, ClosedLoop, MapBackEnd
from twinslam.slam.back_end.place_joining import join_into_place
from twinslam.slam.back_end.pose_graph import LoopEdge
from twinslam.slam.back_end.view_coverage import CoverageBounds, covered_views, served_views
from twinslam.slam.camera import Camera
from twinslam.slam.keyframe import KeyFramePayload
from twinslam.slam.sorted_ids import unique_ids
from twinslam.slot_protocol.map_entry import RESTORED, UNRECORDED
from twinslam.uncertainty.map_uncertainty import map_uncertainty


@dataclass(frozen=True)
class EdgeConfig:
    """The edge's settings for one device: the slot's, which keyframes come back when, and the
    map's life (:class:`~twinslam.slam.back_end.map_back_end.BackEndConfig`, handed to the
    back end as it is)."""

    slot: SlotConfig = field(default_factory=SlotConfig)
    #: archived keyframes brought back a slot at most, where the camera is heading
    #: (:mod:`edge_mapper.restores`); 0: none
    restore_keyframes: int = 0
    #: archived keyframes brought back at the end of a slot around the pose the edge found in
    #: its archive for a lost device's frame (:meth:`EdgeMapperCore.relocalise`); 0: the edge
    #: does not relocalise devices. Off by default: on the 7-Scenes revisit-v15 walk (LFF, 300
    #: frames, 3 seeds) it lost more frames than without (15.0 % / 16.4 % of next-slot frames
    #: with 3 / 15 against 10.8 %, every seed; BENCHMARKS.md)
    reloc_restore_keyframes: int = 0
    #: the map's life: bundle adjustment, archive, fusion, culling, the keyframe gate, loops
    back_end: BackEndConfig = field(default_factory=BackEndConfig)
    #: slots between two checkpoints (with a checkpoint file): each is ~8 ms of the slot on
    #: the 7-Scenes walk's map (its arrays 1.4 ms, written and synced 6.6;
    #: ``bench.edge_scaling --checkpoint-every``); an edge resumed from one up to this many
    #: slots old goes on from the version its device holds
    checkpoint_every: int = 1
    #: a tracked frame whose view a keyframe another device uploaded covers (one of the
    #: map's, lent after a map merge) is not uploaded (:mod:`twinslam.slam.back_end.
    #: view_coverage`)
    coverage: CoverageBounds = field(default_factory=CoverageBounds)
    #: the device's own keyframes cover a frame's view too (by :attr:`coverage`) once they
    #: are views of an earlier visit — restored from the archive, or uploaded at least this
    #: many slots before — while the camera heads where the device was
    #: (:meth:`EdgeMapperCore.covered_frames`); 0: they cover nothing, and a device alone
    #: uploads as Theorem 1 sizes it (the paper's)
    own_coverage_after_slots: int = 0


@dataclass
class SlotOutcome:
    slot: int
    integrated: list[int]            #: keyframes added this slot
    missing: list[int]               #: asked for, never received
    evicted: list[int]
    #: of C_k, kept because uploads it made room for never came (:func:`applied_evictions`)
    spared: list[int]
    orphaned_points: int
    bundle_adjustment: BundleAdjustmentResult | None
    map_uncertainty: float           #: u(G) after the slot (+inf if disconnected)
    version: int
    #: device tracks resolved to map points in this slot and the previous one
    tracks: dict[int, int] = field(default_factory=dict)
    #: milliseconds of each step of ``finish_slot``: archive, optimise, checkpoint, uncertainty
    timings_ms: dict[str, float] = field(default_factory=dict)
    #: archived keyframes that left the archive to keep its capacity
    forgotten: list[int] = field(default_factory=list)
    #: archived keyframes brought back into the map (each replacing one of ``evicted``)
    restored: list[int] = field(default_factory=list)
    #: uploads the keyframe gate refused, with why: they count as never received
    refused: dict[int, str] = field(default_factory=dict)
    #: why the bundle adjustment's answer was not applied ("": applied, or none ran)
    optimisation_refused: str = ""
    #: points the restored keyframes brought back that duplicated map points and were fused
    #: into them (:mod:`twinslam.slam.back_end.point_fusion`)
    fused_points: int = 0
    #: the loop closed at this slot's end, its corrections in the map sent next (None: none)
    loop: ClosedLoop | None = None
    #: why the loop closer's work beside the slots failed since the last slot (the corrected
    #: archive's poses not written: a restart would read the poses before the loop)
    loop_failures: list[str] = field(default_factory=list)

    @property
    def not_in(self) -> list[int]:
        """Uploads asked for that neither arrived in time nor were refused: the device no
        longer held them, or they were lost or late (MapStats' ``missing_keyframes``)."""
        return sorted(set(self.missing) - self.refused.keys())


class EdgeMapperCore:
    """One device's slots at the edge: plans, the keyframes they ask for, evictions, restores,
    the map update's version and the checkpoint, around the map's life in its
    :class:`~twinslam.slam.back_end.map_back_end.MapBackEnd`."""

    def __init__(self, policy: MapPolicy, intrinsics: np.ndarray | None = None,
                 config: EdgeConfig | None = None, checkpoint: Path | None = None,
                 n_states: int = 2) -> None:
        self.config = config or EdgeConfig()
        if self.config.checkpoint_every < 1:
            raise ValueError(f"checkpoint_every is 1 or more slots, not "
                             f"{self.config.checkpoint_every}")
        self.checkpoint = Path(checkpoint) if checkpoint else None
        self._unsaved = 0                 #: slots finished since the last checkpoint
        #: slots until the next checkpoint (:meth:`spread_checkpoints` shifts it)
        self._checkpoint_in = self.config.checkpoint_every
        self.back_end = MapBackEnd(self.config.back_end, intrinsics, self.checkpoint)
        #: what the back end keeps of this device (its own back end's, until its map joins a
        #: place's: :meth:`join_place`)
        self._device = self.back_end.device
        #: the device's ids as its place names them (none renamed until it joins a place)
        self.ids = PlaceIds()
        #: arrays another part of the edge keeps in this device's checkpoint, read when it is
        #: written (the place this map was merged into, :mod:`edge_mapper.place_membership`);
        #: read back from :attr:`MapBackEnd.extra`
        self.saved_with: Callable[[], Mapping[str, np.ndarray]] | None = None
        self._writer: CheckpointWriter | None = None
        extra = self.back_end.extra
        self.last_slot = int(extra.get("last_slot", -1))
        self.rate_history = [int(x) for x in extra.get("rate_history", [])]
        #: the device's tracks resolved in the last finished slot: the next map update lists
        #: them again, in case the device missed the update that first did
        self._previous_tracks: dict[int, int] = {}
        #: after this device's map joined a place (:meth:`join_place`): each point id of
        #: what it held → the place's id of that point, listed once, in its next map update,
        #: beside the tracks resolved — the device relabels its points by it, and goes on
        #: tracking them (by their old ids it would find none of them in the update, or
        #: another device's point of the same id); once only: after that update an old id
        #: may name another device's point it holds
        self._renamed: dict[int, int] = {}
        if self.back_end.restored_from_file:    # a restarted edge resolves the tracks as before
            self.local_mapping.track_points = _table(extra, "track")
            self._previous_tracks = _table(extra, "previous_track")
        self.planner = SlotPlanner(self.slice, at_the_edge(policy), self.config.slot, n_states,
                                   self.device.entered)
        self.pending: dict[int, tuple[MapAction, set[int]]] = {}   #: slot → (action, received)
        self._planned_vmax: dict[int, int] = {}   #: open slot → the V_max it was planned with
        #: requested uploads not integrated yet, as the slot's summaries observed them
        self._arriving: dict[int, FrameObservations] = {}
        #: keyframes of a slot that arrived while an earlier slot was open
        self._held: dict[int, list[KeyFramePayload]] = {}
        #: open slot → its uploads the keyframe gate refused, with why
        self._refused: dict[int, dict[int, str]] = {}
        self.restored = self.last_slot >= 0
        #: open slot → where the camera is predicted to be after it (that slot's restores look
        #: there, whenever the slot finishes: a late slot does not borrow a newer slot's view)
        self._headings: dict[int, list[np.ndarray]] = {}
        self._last_heading: list[np.ndarray] = []   #: kept while the device is lost
        #: where the newest planned slot's last tracked frame was and where the camera heads
        #: after it: what another device's keyframes must be in view of to be lent to this
        #: map (:meth:`in_coming_view`); empty until a slot is planned, and while lost
        self._seen_from: list[np.ndarray] = []
        #: poses found in the archive for the lost device's frames since the last finished slot:
        #: where the next restores look instead of the heading
        self._relocalised_views: list[np.ndarray] = []

    # -- the map's life, in the back end -----------------------------------------------------

    @property
    def map(self) -> KeyFrameMap:
        """The map the device's keyframes live in (its place's): what the back end edits."""
        return self.back_end.map

    @property
    def device(self) -> DeviceRecord:
        """What the back end keeps of this device beside its place's map: its slice, camera,
        tracks, entry order and the frame of each map version it was sent."""
        return self._device

    @property
    def serves_place(self) -> bool:
        """Whether this core runs its place's bundle adjustment and checkpoint and sets its
        loop search: every core but one whose device's map joined another device's place
        (:meth:`join_place`). The place's loops are taken and started at every device's slot
        end (one job at a time: :meth:`MapBackEnd.start_loop_job`)."""
        return self._device is self.back_end.device

    @property
    def version(self) -> int:
        """The newest map version the device was sent (:attr:`DeviceRecord.version`)."""
        return self.device.version

    @version.setter
    def version(self, version: int) -> None:
        self.device.version = version

    @property
    def slice(self) -> KeyFrameSlice:
        """The keyframes of :attr:`map` the device holds: what its plans, map update, map
        uncertainty, evictions, restores and covers read."""
        return self.device.slice

    @property
    def writer(self) -> CheckpointWriter | None:
        """The edge process's checkpoint writer (None: checkpoints are written on the slot
        thread, before the slot's map update goes out). With one, the archive's files are
        written on its thread too, each just before the first checkpoint whose map no longer
        holds its keyframe (:attr:`KeyFrameArchive.write_later`)."""
        return self._writer

    @writer.setter
    def writer(self, writer: CheckpointWriter | None) -> None:
        if writer is None and self.archive.write_later:
            self.archive.write_owed()          # back on the slot thread: nothing left owed
        self._writer = writer
        self.archive.write_later = writer is not None

    @property
    def archive(self) -> KeyFrameArchive:
        return self.back_end.archive

    @property
    def k(self) -> np.ndarray:
        """The camera's intrinsics (the identity until the first keyframe brings them)."""
        return self.device.k

    @property
    def camera(self) -> Camera:
        """The device's camera as the edge knows it (:attr:`DeviceRecord.camera`)."""
        return self.device.camera

    @property
    def local_mapping(self) -> LocalMapping:
        return self.device.local_mapping

    @property
    def loop_closer(self) -> LoopCloser:
        return self.back_end.loop_closer

    @property
    def loops_closed(self) -> int:
        return self.back_end.loops_closed

    @property
    def loops_refused(self) -> int:
        return self.back_end.loops_refused

    @property
    def loop_edges(self) -> list[LoopEdge]:
        return self.back_end.loop_edges

    @property
    def frame_correction(self) -> np.ndarray:
        """The frame the map is in (MapUpdate.frame_correction)."""
        return self.device.frame_correction

    @property
    def archive_problems(self) -> list[str]:
        """What the archive could not read back after a restart (the node logs it)."""
        return self.back_end.archive_problems

    @staticmethod
    def warm_up(policy: MapPolicy) -> None:
        """One slot of a tiny made-up map through ``policy``, υ, eviction and the optimiser,
        so the compiled kernels are loaded (or compiled, in a fresh checkout: tens of seconds)
        before the first real slot arrives instead of while the device waits for its map.
        A copy of ``policy`` decides, so one that learns from its slots (``mpc``'s rate twin)
        starts the real run from nothing."""
        core = EdgeMapperCore(copy.deepcopy(policy), None,
                              EdgeConfig(slot=SlotConfig(vmax=3),
                                         back_end=BackEndConfig(ba_window=WARM_UP_BA_WINDOW)))
        for kf in range(3):
            core.map.add_keyframe(kf, np.eye(4))
        for p in range(40):
            pid = core.map.add_point(np.array([0.0, 0.0, 2.0]), np.zeros(32, np.uint8))
            for kf in range(3):
                if kf * 10 <= p < kf * 10 + 20:
                    core.map.observe(kf, pid, (320.0, 240.0), 2.0)
        frames = [FrameObservations(10 + i, frozenset(range(1 + 5 * i, 21 + 5 * i)))
                  for i in range(6)]
        core.plan(0, frames, 40.0, 0)
        core.finish_slot(0)

    def restored_summary(self) -> str:
        """What a restart resumed from, in one line."""
        return (f"restored map version {self.version} (slot {self.last_slot}, "
                f"{len(self.slice.keyframes)} keyframes, {len(self.slice.points)} points, "
                f"{len(self.local_mapping.track_points)} device tracks resolved, "
                f"{len(self.archive)} archived keyframes) from {self.checkpoint}")

    def set_policy(self, policy: MapPolicy) -> None:
        """The policy that decides from the next plan on (``mpc`` planning in a world of this
        map, :func:`~edge_mapper.planning_world.at_the_edge`)."""
        self.planner.policy = at_the_edge(policy)

    @property
    def slot_config(self) -> SlotConfig:
        """The slot's settings now, V_max included: the planner owns them (``config.slot`` is
        only what the core started with)."""
        return self.planner.config

    def set_bundle_adjustment(self, window: int, points: int | None) -> None:
        """The local bundle adjustment from the next slot on: ``window`` newest keyframes (0:
        none), at most ``points`` points (an edge over its compute budget trims it,
        :mod:`edge_mapper.compute_governor`; ``config.back_end`` is only what the core
        started with, the back end's own config holds the adjustment now). A device that
        joined another's place has none of its own: the place's is that device's core's."""
        if self.serves_place:
            self.back_end.set_bundle_adjustment(window, points)

    def set_loop_search(self, on: bool) -> None:
        """New loop searches start at the slots' ends from now on, or none does (an edge over
        its compute budget pauses them: :mod:`edge_mapper.compute_governor`); the place's
        own core's setting where this device joined another's place."""
        if self.serves_place:
            self.back_end.loop_search_paused = not on

    def set_vmax(self, vmax: int) -> None:
        """V_max from the next plan on (a smaller one evicts the excess over the next slots'
        C_k, as Theorem 1's sizes allow)."""
        self.planner.config = dataclasses.replace(self.planner.config, vmax=int(vmax))

    # -- the protocol ------------------------------------------------------------------------

    def plan(self, slot: int, frames: list[FrameObservations], rate_mbps: float, rate_state: int,
             *, tracks_resolved: bool = False) -> SlotPlan:
        """U_k and C_k for slot ``slot``'s ``frames`` (:meth:`SlotPlanner.plan`), their track
        ids resolved first (:meth:`resolve_tracks`) unless ``tracks_resolved``: the caller
        resolved these very frames since the last keyframe was integrated (the edge node
        does, for the keyframe budget; resolving them again finds nothing, and looked every
        frame's tracks up in the table again: 0.56 ms a device-slot, median, over the
        7-Scenes walk in ``bench.edge_work``)."""
        self.rate_history = [*self.rate_history[-63:], int(rate_state)]
        if slot in self.pending:
            raise ValueError(f"slot {slot} is planned already and still open")
        if not tracks_resolved:        # (resolving renames a joined device's ids too)
            frames = self.resolve_tracks(frames)
        leaving = {kf for action, _ in self.pending.values() for kf in action.evict}
        ahead = heading(frames)
        plan = self.planner.plan(slot, frames, rate_mbps, rate_state, self.rate_history,
                                 self._arriving, leaving, self.camera,
                                 self.covered_frames(frames, slot, ahead, leaving))
        self.pending[slot] = (plan.action, set())
        self._planned_vmax[slot] = self.planner.config.vmax
        self._last_heading = self._headings[slot] = ahead or self._last_heading
        self._seen_from = seen_from(frames, ahead)
        by_id = {f.frame_id: f for f in frames}
        self._arriving.update({f: by_id[f] for f in plan.action.upload})
        return self._as_device_sees(plan)

    def _as_device_sees(self, plan: SlotPlan) -> SlotPlan:
        """A plan whose frames — the uploads asked for, the frames covered — the device
        names as its own (:class:`PlaceIds`); the evictions are keyframes of its slice, as
        its map updates name them."""
        if not self.ids.tag:
            return plan
        frames = self.ids.device_frame

        def asked(action: MapAction) -> MapAction:
            return dataclasses.replace(action, upload=[frames(f) for f in action.upload])

        return dataclasses.replace(
            plan, action=asked(plan.action), covered=frozenset(map(frames, plan.covered)),
            policy_action=None if plan.policy_action is None else asked(plan.policy_action))

    def covered_frames(self, frames: Sequence[FrameObservations], slot: int,
                       ahead: Sequence[np.ndarray],
                       leaving: Collection[int] = frozenset()) -> dict[int, int]:
        """The tracked ``frames`` of ``slot`` whose views a keyframe of the map covers
        (``config.coverage``; the keyframes ``leaving`` with open slots' evictions left out),
        each with the map points it must share with the map to be left out of the uploads
        (``coverage.min_points``): one another device uploaded, or with
        ``own_coverage_after_slots`` one of the device's own from an earlier visit
        (:meth:`_earlier_visit`) while the camera heads where it was before (``ahead``: the
        frames' :func:`heading`, :meth:`_heads_where_it_was`); with ``coverage.by_points``
        also a frame that shares ``coverage.min_points`` of its reported points with the
        keyframes other devices lent, wherever it stands (:func:`served_views`). A frame's
        pose is in the frame of the map version it was tracked on (-1: unknown, taken as
        now's); a loop or a merge applied since moves it into the map's frame now first."""
        bounds = self.config.coverage
        if not bounds.enabled:
            return {}
        held = self.slice.keyframes
        owns = self.device.owns                 # another device's: lent, or its place's
        lent_ids = [k for k in held if k not in leaving and not owns(k)]
        lent = [held[k].pose for k in lent_ids]
        own = [kf.pose for k, kf in held.items()
               if k not in leaving and owns(k) and self._earlier_visit(k, slot)]
        if own and not self._heads_where_it_was(frames, ahead, own):
            own = []
        if not lent and not own:
            return {}
        poses = {f.frame_id: self.device.moved_since(f.map_version) @ f.pose
                 for f in frames if f.tracked and f.pose is not None}
        covered = covered_views(poses, lent + own, bounds)
        if bounds.by_points and lent_ids:
            # a frame's keys hold its track ids as negative keys, never among map points
            matched = {f.frame_id: f.keys for f in frames
                       if f.tracked and f.frame_id not in covered}
            lent_points = unique_ids(np.concatenate([self.slice.point_array(k)
                                                     for k in lent_ids]))
            covered |= served_views(matched, lent_points, bounds)
        return dict.fromkeys(covered, bounds.min_points)

    def _heads_where_it_was(self, frames: Sequence[FrameObservations],
                            ahead: Sequence[np.ndarray], own: Sequence[np.ndarray]) -> bool:
        """Whether every pose the camera heads to after ``frames`` (``ahead``: their
        :func:`heading`, in the frame of their newest tracked one's map version) stands
        where the device was before: beside one of its ``own`` keyframes of an earlier visit
        in the map, or beside an archived keyframe, which the slot's restores bring in where
        the camera heads. A device about to leave the ground it knows uploads as Theorem 1
        sizes it, though its present views are covered: the next slot needs keyframes the
        map does not hold yet, and its frames were lost where the slot before it uploaded
        nothing (docs/results/shared-map.md). False where no frame was tracked."""
        if not ahead:
            return False
        newest = max((f for f in frames if f.tracked and f.pose is not None),
                     key=lambda f: f.frame_id)
        move = self.device.moved_since(newest.map_version)
        poses = {i: move @ pose for i, pose in enumerate(ahead)}
        known = [*own, *(kf.pose for kf in self.archive)]
        return len(covered_views(poses, known, self.config.coverage)) == len(poses)

    def _earlier_visit(self, keyframe: int, slot: int) -> bool:
        """Whether the device's own ``keyframe`` is a view of an earlier visit at ``slot``:
        restored from the archive (the device left that place and came back), or uploaded
        ``own_coverage_after_slots`` slots before or more. Never with that setting 0. A
        keyframe of the last few slots is the walk going on, not a visit: a device moving
        slowly would otherwise cover its every view with the keyframe it just uploaded and
        leave the map no denser than the bounds."""
        after = self.config.own_coverage_after_slots
        if after <= 0:
            return False
        entered, how = self.device.entered.get(keyframe, UNRECORDED)
        return how == RESTORED or 0 <= entered <= slot - after

    def is_restart(self, slot: int) -> bool:
        """Whether summaries of ``slot`` come from a device that started again: while a
        device runs its slots only go forward (they count from its first frame's stamp), so
        a slot this edge planned already and closed is a new run's, whose frame ids count
        from the start again too — planned against the old map, its frames would clash with
        the old run's keyframes, or enter a map in a frame the new run never saw (the link
        takes the restart once the new run's next slot follows: a stray message is none)."""
        return slot not in self.pending and slot <= self.newest_planned

    @property
    def newest_planned(self) -> int:
        """The newest slot this edge planned, open or closed (-1: none)."""
        return max(self.last_slot, max(self.pending, default=-1))

    @property
    def oldest_open(self) -> int | None:
        """The open slot that must finish next (slots finish in order)."""
        return min(self.pending) if self.pending else None

    def is_complete(self, slot: int) -> bool:
        """Every keyframe ``slot`` asked for has arrived (integrated or held)."""
        action, received = self.pending[slot]
        return set(action.upload) <= received

    def resolve_tracks(self, frames: Sequence[FrameObservations]) -> list[FrameObservations]:
        """The frames with their track ids that already became map points counted as those
        points (the device reports them as tracks until its next map update relabels them);
        a frame with none is returned as it is, so resolving twice changes nothing and the
        keys a frame made once (:attr:`FrameObservations.keys`) are read again: the edge node
        resolves a slot's frames before the keyframe budget reads them, and hands the plan
        those (:meth:`plan`'s ``tracks_resolved``). A joined device's frames are renamed into
        its place's ids here, once (:class:`~edge_mapper.place_ids.PlaceIds`): frames this
        returned must not come back through it."""
        known = self.local_mapping.track_points       # pruned to the map's points each slot
        resolved = []
        for frame in map(self.ids.observations, frames):
            hits = known.keys() & frame.tracks
            resolved.append(frame if not hits else dataclasses.replace(
                frame, map_points=frame.map_points | {known[t] for t in hits},
                tracks=frame.tracks - hits))
        return resolved

    def add_keyframe(self, data: KeyFramePayload) -> IntegrationReport | None:
        """Integrate a keyframe the plan of its slot asked for — or hold it while an earlier
        slot is open (``IntegrationReport.deferred``); None (and nothing changes) for an
        unrequested or repeated one, or one of a slot that finished already."""
        entry = self.pending.get(data.slot)
        if entry is not None and self.ids.tag:
            observed = self._arriving.get(self.ids.frame(data.frame_id))
            data = self.ids.upload(data, observed.map_version if observed else -1)
        if entry is None or data.frame_id not in entry[0].upload or \
                data.frame_id in entry[1] or data.frame_id in self.map.keyframes:
            return None
        entry[1].add(data.frame_id)
        if data.slot != self.oldest_open:
            self._held.setdefault(data.slot, []).append(data)
            return IntegrationReport.held()
        return self._integrate(data)

    def _integrate(self, data: KeyFramePayload) -> IntegrationReport:
        observed = self._arriving.pop(data.frame_id, None)
        report = self.back_end.integrate(data, observed.map_version if observed else -1,
                                         self.device)
        if report.refused:
            self._refused.setdefault(data.slot, {})[data.frame_id] = report.refused
        return report

    def frame_correction_at(self, version: int) -> np.ndarray:
        """The frame map version ``version`` was in (its ``frame_correction``)."""
        return self.device.frame_correction_at(version)

    def integrate_held(self) -> list[int]:
        """The held keyframes of the slot that is now the oldest open one, integrated (call
        after publishing a finished slot's map); their frame ids."""
        slot = self.oldest_open
        held = self._held.pop(slot, []) if slot is not None else []
        for data in held:
            self._integrate(data)
        return [d.frame_id for d in held]

    def finish_slot(self, slot: int) -> SlotOutcome:
        """Evict C_k (as much of it as the uploads that came need room for, see
        :func:`applied_evictions`), optimise, publish a new map version, checkpoint. Slots
        finish in order: finishing a later slot while an earlier one is open is refused
        (ValueError)."""
        if slot in self.pending and slot != self.oldest_open:
            raise ValueError(f"slot {slot} cannot finish before slot {self.oldest_open}")
        action, received = self.pending.pop(slot, (MapAction([], []), set()))
        vmax = self._planned_vmax.pop(slot, self.planner.config.vmax)
        for frame in action.upload:                  # what has not come will not be used
            self._arriving.pop(frame, None)
        # keyframes held while an older slot was open, if the caller finished this slot
        # without integrate_held() first (the node always calls it; a bare core user may not)
        for data in self._held.pop(slot, []):
            self._integrate(data)
        refused = self._refused.pop(slot, {})
        received -= refused.keys()            # a refused upload is as good as lost
        tl = time.perf_counter()
        # the place's loop closer, at every device's slot end: a place goes on closing loops
        # whichever of its devices walk on (one job at a time, the walks in turn)
        loop = self.back_end.take_loop()
        missing = set(action.upload) - received
        evicted = applied_evictions(action.evict, self.slice.keyframe_ids(), missing, vmax)
        ta = time.perf_counter()
        loop_ms = (ta - tl) * 1e3
        forgotten, orphans = self.back_end.evict_to_archive(evicted, slot, self.device)
        spared = sorted(set(action.evict) - set(evicted) - missing)
        views, self._relocalised_views = self._relocalised_views, []
        # restores fill the map up to the smaller of this slot's V_max and the next one's: an
        # edge serving several devices may already have granted this device more for the next
        # slot, which this slot's map (and its MapStats' budget) must not anticipate
        restored, replaced, dropped, fused = self._restore(
            slot, received, self._headings.pop(slot, []), views,
            min(vmax, self.planner.config.vmax))
        evicted += replaced
        forgotten += dropped
        t0 = time.perf_counter()
        ba = self.back_end.optimise() if self.serves_place else None
        t1 = time.perf_counter()
        self.version += 1
        self.last_slot = slot
        fresh = self.local_mapping.take_new_tracks()
        tracks = {**self._renamed, **self._previous_tracks, **fresh}
        self._previous_tracks, self._renamed = fresh, {}
        # tracks whose point left the map are forgotten: the table stays the map's size
        self.local_mapping.forget_tracks_gone()
        if self.checkpoint is None:
            self.archive.release_taken()
        else:
            self._unsaved += 1
            self._checkpoint_in -= 1
            if self._checkpoint_in <= 0:
                self.save_checkpoint()
        t2 = time.perf_counter()
        w = self.slice.covisibility()
        u = map_uncertainty(w, self.planner.config.log_det_pi) if len(w) else math.inf
        t3 = time.perf_counter()
        self.back_end.start_loop_job(slot)
        t4 = time.perf_counter()
        timings = {"archive": (t0 - ta) * 1e3, "optimise": (t1 - t0) * 1e3,
                   "checkpoint": (t2 - t1) * 1e3, "uncertainty": (t3 - t2) * 1e3,
                   "loop": loop_ms + (t4 - t3) * 1e3}
        return SlotOutcome(slot=slot, integrated=sorted(received), missing=sorted(missing),
                           evicted=evicted, spared=spared, orphaned_points=orphans,
                           bundle_adjustment=ba, map_uncertainty=u, version=self.version,
                           tracks=tracks, timings_ms=timings, forgotten=forgotten,
                           restored=restored, refused=refused,
                           optimisation_refused=ba.refused if ba is not None else "",
                           fused_points=fused, loop=loop,
                           loop_failures=self.loop_closer.failures())

    def save_checkpoint(self) -> None:
        """Write the map as the last finished slot left it to the checkpoint file, then delete
        the archive's files of the keyframes restored into it since the last one. With no
        :attr:`writer`, written before the slot's map update goes out: a map the device was
        sent survives the edge (with ``checkpoint_every`` 1; with more, a restarted edge
        resumes from a map up to that many slots old and goes on from the version its device
        holds, :meth:`catch_up_version`); with one, the arrays are gathered here and written
        on its thread, shortly after the update went out."""
        if self.checkpoint is None:
            raise ValueError("this edge has no checkpoint file to write")
        contents = self.map.checkpoint_contents(
            last_slot=np.array(self.last_slot),
            rate_history=np.array(self.rate_history, dtype=np.int64),
            **self.back_end.checkpoint_arrays(),
            **_table_arrays(self.local_mapping.track_points, "track"),
            **_table_arrays(self._previous_tracks, "previous_track"),
            **(self.saved_with() if self.saved_with is not None else {}))
        archive = self.archive
        if self.writer is None:
            write_checkpoint(self.checkpoint, contents)   # a failed write keeps them taken
            archive.release_taken()           # restored keyframes are in the checkpoint now
        else:
            taken = archive.hand_over_taken()
            self.writer.submit(self.checkpoint, contents,
                               lambda written: archive.release(
                                   taken, in_map=written["keyframe_ids"]),
                               before=archive.write_owed)
        self._unsaved, self._checkpoint_in = 0, self.config.checkpoint_every

    def spread_checkpoints(self, phase: int) -> None:
        """Shift this device's checkpoints by ``phase`` slots (mod ``checkpoint_every``): the
        devices of one edge, whose slots number alike when they start together, then do not
        all write theirs in the same slot."""
        self._checkpoint_in = phase % self.config.checkpoint_every + 1

    def flush_checkpoint(self) -> None:
        """Checkpoint the slots finished since the last checkpoint, if any (an edge that stops
        cleanly leaves its last map on disk), and wait until it is on disk."""
        if self.checkpoint is not None and self._unsaved:
            self.save_checkpoint()
        self.wait_for_checkpoint()

    def wait_for_checkpoint(self) -> None:
        """Until the checkpoint submitted to the :attr:`writer` is on disk (before the file
        is moved aside or given back to another edge); raises where it could not be
        written."""
        if self.checkpoint is not None and self.writer is not None:
            self.writer.wait(self.checkpoint)

    def catch_up_version(self, held: int) -> bool:
        """The device holds map version ``held``: an edge whose own version is older (it
        resumed from a checkpoint written before its last map updates went out) goes on from
        it, since the device ignores a map not newer than the one it holds. True when it
        did."""
        if held <= self.version:
            return False
        self.version = held
        return True

    def close(self) -> None:
        """Stop the loop closer's worker (the node calls it at shutdown; the place's own
        core's where this device joined another's place)."""
        if self.serves_place:
            self.back_end.close()

    def _restore(self, slot: int, received: set[int], poses: list[np.ndarray],
                 relocalised: list[np.ndarray], vmax: int
                 ) -> tuple[list[int], list[int], list[int], int]:
        """Bring archived keyframes seen from ``poses`` (where the camera is heading after
        ``slot``) — or, where the edge relocalised the lost device in its archive, from the
        ``relocalised`` poses — back into the map, each in place of the keyframe that sees
        least of that view (into the archive in its turn); (restored, evicted for them,
        forgotten by the archive to make room for those, points fused); the map stays within
        ``vmax``."""
        camera = self.camera
        if not camera.known:
            return [], [], [], 0
        if relocalised and self.config.reloc_restore_keyframes > 0:
            chosen = plan_relocation_restores(self.slice, self._restorable(slot), relocalised,
                                              camera, vmax,
                                              self.config.reloc_restore_keyframes, slot, received)
        elif self.config.restore_keyframes > 0 and poses:
            chosen = plan_restores(self.slice, self._restorable(slot), poses, camera, vmax,
                                   self.config.restore_keyframes, slot, received)
        else:
            return [], [], [], 0
        dropped, fused = self.back_end.restore(chosen.restore, chosen.evict, slot, self.device)
        return chosen.restore, chosen.evict, dropped, fused

    def _restorable(self, slot: int) -> KeyFrameArchive:
        """The keyframes a restore may bring into the device's slice: the archive's, and in a
        place of several devices the map's keyframes another device holds, as they are at
        ``slot`` (a view: the archive's own record of which keyframes were useful lately is
        not touched by what the restores score in it then)."""
        apart = self.slice.apart
        if not apart:
            return self.archive
        return self.archive.snapshot([ArchivedKeyFrame.of(self.map, k, slot)
                                      for k in sorted(apart)])

    def in_coming_view(self, positions: Sequence[np.ndarray]) -> list[bool]:
        """Which of another device's keyframes (each given by its points' ``positions``, in
        this map's frame) the camera sees from where its newest planned slot left it or
        where it heads after it, as a restore scores an archived keyframe
        (:data:`~edge_mapper.restores.MIN_VISIBLE` of its points in view): another device's
        keyframe is lent to this map once it is (:func:`~twinslam.slam.back_end.map_merging.
        lend_from`). Every one of them before the first tracked slot and while the device is
        lost: wherever it turns up, the edge relocalises it in its archive, the other
        devices' keyframes included."""
        if not self._seen_from or not self.camera.known:
            return [True] * len(positions)
        scores = view_scores(positions, self._seen_from, self.camera)
        return [s >= MIN_VISIBLE for s in scores.tolist()]

    def relocalise(self, points_xy: np.ndarray, descriptors: np.ndarray) -> ArchiveLocation:
        """Find a lost device's frame (its ORB keypoints and descriptors) in the archive. A pose
        that passes the gate is where the keyframes restored at the end of the open slot are
        chosen (the device relocalises itself against the map update that brings them); the
        recognised keyframes count as useful now. Nothing is found while the edge does not
        relocalise (``reloc_restore_keyframes`` 0) or has no camera yet."""
        if self.config.reloc_restore_keyframes <= 0:
            return ArchiveLocation(None, 0, -1, (), "the edge does not relocalise devices "
                                   "(reloc_restore_keyframes is 0)")
        if not self.camera.known:
            return ArchiveLocation(None, 0, -1, (), "no keyframe has told the edge the camera yet")
        found = self.back_end.relocalise(points_xy, descriptors, self.last_slot + 1,
                                         self.device)
        if found.pose is not None:
            self._relocalised_views.append(found.pose)
        return found

    def align(self, alignment: np.ndarray) -> None:
        """Move the device's whole map into another frame by the rigid motion ``alignment``
        (a merge with another device's map of the place,
        :mod:`twinslam.slam.back_end.map_merging`): the map, its archive and where the
        camera is heading, from the next map update on (:meth:`MapBackEnd.align`; call it
        between slots). A device that joined another's place moves with it, never alone
        (ValueError)."""
        if not self.serves_place:
            raise ValueError("a device that joined a place cannot move its map alone: the "
                             "map is its place's")
        self.back_end.align(alignment)
        self._move_views(np.asarray(alignment, dtype=np.float64))

    def _move_views(self, move: np.ndarray) -> None:
        """Where the camera heads and was seen from, moved by the rigid motion ``move`` with
        the map."""
        self._headings = {s: [move @ p for p in poses] for s, poses in self._headings.items()}
        self._last_heading = [move @ p for p in self._last_heading]
        self._seen_from = [move @ p for p in self._seen_from]
        self._relocalised_views = [move @ p for p in self._relocalised_views]

    def join_place(self, place: EdgeMapperCore, tag: int, alignment: np.ndarray,
                   fellows: Sequence[EdgeMapperCore] = ()) -> None:
        """This device's map joined into the map of ``place``'s device — the core of the
        device a merge found it with (:mod:`twinslam.slam.back_end.map_merging`; ``alignment``
        this map's frame into that one's) — under the device tag ``tag``
        (:func:`~twinslam.slam.back_end.place_joining.join_into_place`; call it between
        slots), with the devices that joined this one's place before (``fellows``: the
        cores of every other device of its map, each going on under its tag). From the next
        map update on each device holds its slice of the place's map; the place's bundle
        adjustment and loops are ``place``'s core's to run. Each one's open slots, the
        uploads they wait for and the tracks it resolved are renamed into the place's ids;
        what the device sends from now on is renamed as it comes in
        (:class:`~edge_mapper.place_ids.PlaceIds`). Not yet where either core writes a
        checkpoint: the place's file would need every device's record (ValueError)."""
        if self.checkpoint is not None or place.checkpoint is not None:
            raise ValueError("a device whose edge writes checkpoints cannot join a place yet")
        if not self.serves_place or not place.serves_place or place is self:
            raise ValueError("a device joins the place of a device whose map is its place's, "
                             "once")
        cores = [self, *fellows]
        if len({id(core.device) for core in cores}) != len(cores) or \
                any(core.back_end is not self.back_end for core in fellows) or \
                {id(core.device) for core in cores} != {id(d) for d in self.back_end.devices}:
            raise ValueError("a place joins another with every device of its map, each once")
        held = [core.slice.point_ids() for core in cores]
        records, fused = join_into_place(place.back_end, self.back_end, tag, alignment)
        self.back_end.close()
        new_record = {id(old): new for old, new in
                      zip(self.back_end.devices, records, strict=True)}
        for core, points in zip(cores, held, strict=True):
            record = new_record[id(core.device)]
            core._enter_place(place.back_end, record,
                              PlaceJoin(tag, record.version, fused), alignment, points)

    def _enter_place(self, back_end: MapBackEnd, record: DeviceRecord, join: PlaceJoin,
                     alignment: np.ndarray, held: np.ndarray) -> None:
        """This device goes on as ``record`` of ``back_end``'s place, its map joined into it
        by ``join`` (:meth:`join_place`; ``held``: the points of its slice before): what it
        keeps between slots renamed by the join, and the points it holds told their new
        ids in its next map update."""
        self.back_end, self._device = back_end, record
        self.ids = self.ids.joined(record.tag, join)
        self._renamed = {p: new for p in held.tolist() if (new := join.point(p)) != p}
        self.planner.map, self.planner.entered = record.slice, record.entered
        self.planner.last_seen = {join.keyframe(k): s for k, s in self.planner.last_seen.items()}
        keyframe = join.keyframe
        self.pending = {s: (dataclasses.replace(action,
                                                upload=[keyframe(f) for f in action.upload],
                                                evict=[keyframe(k) for k in action.evict],
                                                restore=[keyframe(k) for k in action.restore]),
                            {keyframe(f) for f in received})
                        for s, (action, received) in self.pending.items()}
        # what came in before the join, in the ids of the map it joined from
        self._arriving = {keyframe(f): join.observations(obs)
                          for f, obs in self._arriving.items()}
        self._held = {s: [join.upload(d) for d in held] for s, held in self._held.items()}
        self._refused = {s: {keyframe(f): why for f, why in refused.items()}
                         for s, refused in self._refused.items()}
        self._previous_tracks = {t: join.point(p) for t, p in self._previous_tracks.items()}
        self._move_views(np.asarray(alignment, dtype=np.float64))

    def lead_place(self) -> list[int]:
        """The device that led this device's place (its core ran the place's bundle
        adjustment) is gone: this device leads the place from now on, its core running the
        adjustment (:meth:`MapBackEnd.hand_over`: the keyframes only the one gone held go to
        the place's archive). The archived keyframes forgotten for room."""
        if self.serves_place:
            raise ValueError("this device leads its place already")
        return self.back_end.hand_over(self.device, max(self.newest_planned, 0))

    def leave_place(self) -> list[int]:
        """This device, which joined another's place, is gone (its edge reclaimed it, its
        work failed, it started again): the keyframes it held that no other device of the
        place holds go to the place's archive, where the others' restores find them
        (:meth:`MapBackEnd.remove_device`); the archived keyframes forgotten for room. The
        core serves no slot after it."""
        if self.serves_place:
            raise ValueError("the device of the place's own map does not leave it")
        return self.back_end.remove_device(self.device, max(self.newest_planned, 0))

    def optimise(self) -> BundleAdjustmentResult | None:
        """The back end's local bundle adjustment (:meth:`MapBackEnd.optimise`)."""
        return self.back_end.optimise()


#: the warm-up's bundle adjustment, whatever the edge's: a window set live (or by the
#: compute governor) finds its kernels loaded
WARM_UP_BA_WINDOW = 5


def set_aside(kept: Path) -> Path:
    """Where a reclaimed device's checkpoint file, or its archive's folder, is moved aside
    (``FILE.reclaimed``): kept to inspect or restore, and read for the run of the device's
    next map (:func:`~edge_mapper.place_membership.run_after`)."""
    return kept.with_name(kept.name + ".reclaimed")


def applied_evictions(evict: Sequence[int], map_ids: Sequence[int], missing: Collection[int],
                      vmax: int) -> list[int]:
    """The keyframes a slot evicts once its uploads are in: C_k, less one for each requested
    keyframe that never came, and never fewer than keep the map within ``vmax``.

    Theorem 1 sizes C_k to make room for U_k; evicting all of it when uploads are lost (the
    device no longer held the frames, the link dropped them, the device was lost and uploaded
    nothing) shrinks the map for uploads that never came — slot after slot, down to a
    disconnected handful of keyframes. ``map_ids`` is the map with the slot's arrived uploads
    in, oldest first; a keyframe of C_k that is not in it (a lost upload the plan also meant
    to evict) costs nothing. C_k leaves in the order the policy lists it (the rules list it
    by frame id: the oldest first); where C_k cannot bring the map within ``vmax`` (slots
    overlapped and an earlier one spared keyframes the next plan counted out) the oldest other
    keyframes follow.
    """
    in_map = set(map_ids)
    planned = [kf for kf in evict if kf in in_map]
    spare = len(set(missing) - set(evict))
    n = max(len(planned) - spare, len(map_ids) - vmax, 0)
    chosen = planned[:n]
    if n > len(chosen):
        taken = set(chosen)
        chosen += [kf for kf in map_ids if kf not in taken][:n - len(chosen)]
    return chosen


def seen_from(frames: Sequence[FrameObservations], ahead: list[np.ndarray]
              ) -> list[np.ndarray]:
    """The slot's last tracked frame's pose and ``ahead``, where the camera heads after it
    (:func:`heading` of the slot's frames); empty when no frame of the slot was tracked."""
    posed = [f.pose for f in frames if f.tracked and f.pose is not None]
    return [posed[-1], *ahead] if posed else []


def heading(frames: Sequence[FrameObservations]) -> list[np.ndarray]:
    """Where the camera will be over the next slot, from the slot's tracked frames with a
    pose: half a slot and a whole slot past its last frame, at constant velocity (empty when
    no frame of the slot was tracked: the device is lost, its poses are guesses)."""
    posed = [(i, f.pose) for i, f in enumerate(frames) if f.tracked and f.pose is not None]
    if not posed:
        return []
    positions = [i for i, _ in posed]
    n = len(frames)
    after_last = n - 1 - positions[-1]
    return extrapolate([p for _, p in posed], positions,
                       [after_last + max(n // 2, 1), after_last + n])


def _table_arrays(table: dict[int, int], name: str) -> dict[str, np.ndarray]:
    """A device track id → map point id table as the checkpoint's two arrays."""
    return {f"{name}_ids": np.fromiter(table, dtype=np.uint64, count=len(table)),
            f"{name}_point_ids": np.fromiter(table.values(), dtype=np.uint64,
                                             count=len(table))}


def _table(extra: dict[str, np.ndarray], name: str) -> dict[int, int]:
    """The table :func:`_table_arrays` wrote (empty in a checkpoint written before it)."""
    return dict(zip((int(t) for t in extra.get(f"{name}_ids", [])),
                    (int(p) for p in extra.get(f"{name}_point_ids", [])), strict=True))
