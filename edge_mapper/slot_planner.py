"""The edge's per-slot decision from a device's frame summaries (docs/architecture.md §1 steps 3
and 6).

The device reports each frame of slot k as the sets of ids it observes: global map-point ids
from the last map update and device-local track ids of new features. The covisibility weight
between two frames is the size of the intersection of those sets, and between a frame and a
keyframe of the edge's map the number of map points both observe. With these weights the
planner builds the same :class:`~twinslam.policies.actions.SlotObservation` the
simulator gives the policies, asks the configured policy for U_k and C_k (Theorem 1's sizes),
checks the answer, and scores the slot: υ over F_k against the current map (eq. 8), the reward
of the previous decision.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

import numpy as np

from twinslam.policies.actions import MapAction, SlotObservation, check_map_action
from twinslam.policies.connected_map import STALE_SLOTS, connected_action, seen_keyframes
from twinslam.policies.protocol import MapPolicy, SlotViewer
from twinslam.slam.back_end.keyframe_map import shared_counts
from twinslam.slam.back_end.keyframe_slice import MapView
from twinslam.slam.back_end.view_coverage import uploads_for_new_views
from twinslam.slam.camera import Camera
from twinslam.slam.keyframe import track_counters
from twinslam.slam.sorted_ids import held_counts, unique_ids
from twinslam.slot_protocol.lost_frame_rule import MIN_INLIERS
from twinslam.slot_protocol.map_entry import entry_order
from twinslam.slot_protocol.slot_settings import SlotSettings
from twinslam.uncertainty.map_uncertainty import (
    SlotUncertainty,
    needs_map,
    next_slot_uncertainty,
    theorem1_cardinalities,
    theorem1_evictions,
    waited_after,
)


@dataclass(frozen=True)
class FrameObservations:
    """One frame of a slot as the planner sees it (``FrameSummary`` without the pose)."""

    frame_id: int
    map_points: frozenset[int]         #: global map-point ids
    tracks: frozenset[int] = frozenset()   #: device-local track ids (only shared in-slot)
    #: the device tracked it; an untracked frame's pose is a guess, and a keyframe placed by
    #: a guess would put its points in the wrong place: it is scored but never uploaded
    tracked: bool = True
    #: the device's camera-to-map pose estimate (4×4), when the summary carried one: where the
    #: camera is heading, for a planner that predicts the next frames (edge_mapper.planning_world)
    pose: np.ndarray | None = field(default=None, compare=False)
    #: the map version the device tracked it against (FrameSummary.map_version; -1: unknown):
    #: a loop's correction applied after that version has not reached its pose yet
    map_version: int = -1

    @functools.cached_property
    def keys(self) -> np.ndarray:
        """The ids it observes as one int64 key set without repeats (read-only): map points
        as they are, track ids (their own namespace) as negative keys, so they never equal a
        map-point id. Made once a frame: the keyframe budget's demand, the plan's weights and
        the slot's υ each read every frame's."""
        tracks = track_counters(np.fromiter(self.tracks, dtype=np.uint64,
                                            count=len(self.tracks)))
        keys = np.concatenate([np.fromiter(self.map_points, dtype=np.int64,
                                           count=len(self.map_points)), -1 - tracks])
        keys.flags.writeable = False
        return keys


@dataclass(frozen=True)
class SlotConfig(SlotSettings):
    """The slot protocol's settings (:class:`~twinslam.slot_protocol.slot_settings.
    SlotSettings`: V_max, α, D_req, the progress rule, the deadline it stretches to) and the
    edge's Π; the slot's length F comes with each slot's summaries."""

    log_det_pi: float = 0.0
    #: where the policy's uploads or evictions would leave the map in more pieces, the newest
    #: frames that tie to it and keyframes whose eviction splits nothing instead
    #: (:mod:`twinslam.policies.connected_map`, the edge's ``connected_map``); False: the
    #: policy's decision as it is (the paper's edge)
    connected_map: bool = True


@dataclass(frozen=True)
class SlotView:
    """What the edge knows of a slot when it decides, beyond the policy's observation: the
    map, the frames (poses included) and the camera. The slot planner hands it to a policy
    that asks for it (``see_slot``) just before ``decide``."""

    keyframe_map: MapView
    map_ids: list[int]                        #: the observation's map (arriving uploads too)
    frames: list[FrameObservations]           #: the slot's frames, capture order
    points_of: Callable[[int], np.ndarray]    #: the int64 keys a keyframe or frame observes
    camera: Camera
    config: SlotConfig


@dataclass
class SlotPlan:
    action: MapAction
    observation: SlotObservation
    uncertainty: SlotUncertainty | None     #: υ of F_k against the map; None if the map is empty
    #: tracked frames left out of the candidates: the map covers their views already
    covered: frozenset[int] = frozenset()
    #: the policy's own decision where it would have left the map in more pieces and
    #: ``action`` is mended (``connected_map``); None: ``action`` is the policy's
    policy_action: MapAction | None = None
    #: each of the slot's frames (capture order): the map points its reported points share
    #: with the map it was planned on, and whether the lost-frame rule counts it lost —
    #: what a bench records frame by frame (the slot's υ keeps only the sums)
    shared: tuple[int, ...] = ()
    lost: tuple[bool, ...] = ()


class SlotPlanner:
    """Builds observations over the map a device holds (a :class:`KeyFrameMap`, or the
    device's :class:`~twinslam.slam.back_end.keyframe_slice.KeyFrameSlice` of its place's)
    and runs a policy on them."""

    def __init__(self, keyframe_map: MapView, policy: MapPolicy,
                 config: SlotConfig | None = None, n_states: int = 2,
                 entered: Mapping[int, tuple[int, int]] | None = None) -> None:
        self.map = keyframe_map
        #: when each map keyframe entered the map, (slot, phase) (read, never changed here):
        #: the observation's entry order, a rule's "oldest" (none: the ids' order)
        self.entered: Mapping[int, tuple[int, int]] = entered if entered is not None else {}
        self.policy = policy
        self.config = config or SlotConfig()
        self.n_states = n_states
        #: what the uplink carried while this device, needing a map, waited for an upload
        #: (:func:`~twinslam.uncertainty.map_uncertainty.waited_after`): it is served first
        self.waited_mbit = 0.0
        #: the last slot in which a tracked frame tied to each map keyframe's piece (or the
        #: keyframe entered the map): a piece left that long ago is dropped from a map in
        #: pieces (:data:`~twinslam.policies.connected_map.STALE_SLOTS`)
        self.last_seen: dict[int, int] = {}

    def weights(self, frames: dict[int, FrameObservations], a: list[int], b: list[int]
                ) -> np.ndarray:
        """w between ids in ``a`` and ``b``, each a keyframe of the map or a frame of the slot;
        zero between an id and itself."""
        ids = list(dict.fromkeys([*a, *b]))
        full = self.weight_matrix(frames, ids)
        pos = {x: i for i, x in enumerate(ids)}
        return full[np.ix_([pos[x] for x in a], [pos[x] for x in b])]

    def weight_matrix(self, frames: dict[int, FrameObservations], ids: list[int]) -> np.ndarray:
        """w among ``ids`` (keyframes and slot frames) as one sparse product."""
        return shared_counts([self.points_of(frames, x) for x in ids])

    def points_of(self, frames: dict[int, FrameObservations], frame_id: int) -> np.ndarray:
        """The ids a keyframe or slot frame observes as one int64 key set: map points as
        they are, track ids (their own namespace) as negative keys so they never equal a
        map-point id."""
        if frame_id in self.map.keyframes:
            return self.map.point_array(frame_id)
        return frames[frame_id].keys

    def plan(self, slot: int, frames: list[FrameObservations], rate_mbps: float, rate_state: int,
             rate_history: list[int], arriving: dict[int, FrameObservations] | None = None,
             leaving: frozenset[int] | set[int] = frozenset(),
             camera: Camera | None = None, covered: Mapping[int, int] | None = None
             ) -> SlotPlan:
        """U_k and C_k for slot k's frames (capture order) at rate d_k. The policy chooses U_k
        among the frames the device tracked; υ is scored over all of them.

        With earlier slots still open (their uploads on the way, their evictions not yet
        applied — slots shorter than their upload time), the map the decision is sized and
        scored against is the one those slots will leave: ``arriving`` uploads (not yet in the
        map, as their frames were observed) join it, ``leaving`` keyframes are left out.
        ``camera`` goes with the map and frames to a policy that predicts what the camera will
        see (``see_slot``, the edge's ``mpc``). ``covered`` frames (views the map holds already,
        :mod:`twinslam.slam.back_end.view_coverage`, each with the map points it must share
        with the map) are no candidates, unless the map cannot serve them so (sharing fewer:
        lost by the rule below, or near it where the cover asks for a margin): a slot whose
        tracked frames are all covered and served asks for no upload, whatever the uplink
        could carry, and one with some covered spends the count the uplink allows for all its
        tracked frames at the same density on the rest
        (:func:`~twinslam.slam.back_end.view_coverage.uploads_for_new_views`).
        """
        if not frames:
            raise ValueError(f"slot {slot}: no frames to plan with")
        by_id = {f.frame_id: f for f in frames}
        if len(by_id) != len(frames):
            raise ValueError(f"slot {slot}: frame ids repeat")
        arriving = {f: o for f, o in (arriving or {}).items()
                    if f not in leaving and f not in self.map.keyframes}
        map_ids = [k for k in self.map.keyframe_ids() if k not in leaving] + sorted(arriving)
        every = [f.frame_id for f in frames]
        clash = set(every) & set(map_ids)
        if clash:
            raise ValueError(f"slot {slot}: frames {sorted(clash)} are already keyframes")
        cfg = self.config
        seen = {**arriving, **by_id}
        # each keyframe's and frame's point keys, made once: the weights, the policy's view
        # and the slot's υ all read them
        keys = {x: self.points_of(seen, x) for x in map_ids + every}
        # the map's keyframes (a prefix of map_ids) counted as the slot's end counted them
        kept = [k for k in map_ids if k in self.map.keyframes]
        counted = self.map.incidence(kept)
        # a frame is lost when its reported points (the device's matches) share fewer than
        # the device's MIN_INLIERS with the map (twinslam.slot_protocol.lost_frame_rule); a
        # keyframe holds map-point ids only, so this counts shared map points alone
        in_map = (unique_ids(np.concatenate([counted.points, *(keys[x] for x in arriving)]))
                  if arriving else counted.points)
        shared = held_counts([keys[f] for f in every], in_map)
        lost = [not f.tracked or n < MIN_INLIERS for f, n in zip(frames, shared, strict=True)]
        # a covered frame the map does not serve as its cover asks (the device matched fewer
        # of the map's points: lost by the rule, or near it where the cover asks for a
        # margin) stays a candidate: the view's keyframe is there, its points are not what
        # the device sees
        covered = covered or {}
        skipped = frozenset(f.frame_id for f, gone, n in zip(frames, lost, shared, strict=True)
                            if f.frame_id in covered and not gone and n >= covered[f.frame_id])
        cand = [f.frame_id for f in frames if f.tracked and f.frame_id not in skipped]
        slot_s = cfg.deadline_s(len(frames))
        # with covered views, the uplink's count for the slot's tracked frames goes to the
        # views the map lacks at the density a device alone spends it (view_coverage)
        views = len(cand) + len(skipped)
        n_up, n_ev = theorem1_cardinalities(rate_mbps, cfg.alpha_mbit, cfg.d_req_s, cfg.vmax,
                                            len(map_ids), views, slot_s, self.waited_mbit)
        if skipped:
            n_up = uploads_for_new_views(n_up, len(cand), views)
            n_ev = theorem1_evictions(len(map_ids), n_up, cfg.vmax)
        self.waited_mbit = waited_after(n_up, rate_mbps, slot_s, self.waited_mbit,
                                        needs_map(lost))
        full = counted.extended([keys[x] for x in map_ids[len(kept):] + every])
        pos = {x: i for i, x in enumerate(map_ids + every)}
        # the map's keyframes in the order they entered it, then the uploads on their way
        entered = entry_order(kept, self.entered) + map_ids[len(kept):]
        obs = SlotObservation(slot, map_ids, cand, n_up, n_ev, rate_mbps, rate_state,
                              list(rate_history), self.n_states,
                              lambda a, b: full[np.ix_([pos[x] for x in a],
                                                       [pos[x] for x in b])],
                              entered=entered)
        if isinstance(self.policy, SlotViewer):
            self.policy.see_slot(SlotView(self.map, map_ids, list(frames),
                              lambda x: keys[x] if x in keys else self.points_of(seen, x),
                              camera or Camera(), cfg))
        action = self.policy.decide(obs)
        check_map_action(slot, n_up, n_ev, set(cand), map_ids, action)
        chosen = action
        if cfg.connected_map:
            action = connected_action(obs, action, self._stale(slot, map_ids, frames, full))
        mended = chosen if action is not chosen else None
        # υ of F_k against the map as it is (eq. 8), None for an empty map
        m = len(map_ids)
        counts = tuple(shared.tolist())
        if not m:
            return SlotPlan(action, obs, None, skipped, mended, counts, tuple(lost))
        upsilon = next_slot_uncertainty(full[:m, :m], full[m:, :m], self.config.log_det_pi,
                                        shared >= MIN_INLIERS)
        return SlotPlan(action, obs, upsilon, skipped, mended, counts, tuple(lost))

    def _stale(self, slot: int, map_ids: list[int], frames: list[FrameObservations],
               full: np.ndarray) -> set[int]:
        """The map keyframes whose piece no tracked frame has tied to for
        :data:`STALE_SLOTS` slots (this one's frames counted: ``full`` holds the weights
        among ``map_ids`` and then the slot's ``frames``)."""
        m = len(map_ids)
        tracked = [m + i for i, f in enumerate(frames) if f.tracked]
        seen = seen_keyframes(full[:m, :m], full[np.ix_(tracked, range(m))])
        last = {k: self.last_seen.get(k, slot) for k in map_ids}
        last.update((k, slot) for k, s in zip(map_ids, seen, strict=True) if s)
        self.last_seen = last
        return {k for k, s in last.items() if slot - s >= STALE_SLOTS}


