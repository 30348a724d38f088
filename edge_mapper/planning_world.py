"""The world the causal planner ``mpc`` imagines at the edge, built from the live map.

In the simulator ``mpc`` (:mod:`twinslam.policies.mpc`) plans in the simulator's own world:
the covisibility dataset tells it which points the next frames see. Live nothing tells it; the
edge has to predict the next slots' frames from what it knows when it decides:

* **where the camera goes** — the device's poses of the slot's tracked frames: the rigid
  motion from the first to the last of them, per frame, continued at constant velocity
  (:func:`extrapolate`);
* **what it will see there** — what the nearest view the edge knows (a keyframe, or a frame
  of the slot) saw, nearest by distance and turn: its map points that fall in the camera's
  frustum at the extrapolated pose (projected with the device's intrinsics, in front and
  within ``max_depth_m``; occlusion is not modelled) and of its new features (device track
  ids, without a 3-D position yet) the same share; then thinned as the slot's own frames
  thin out — the share of a frame's points a frame Δ later still sees, fitted to this slot
  (:func:`overlap_decay`) — so the frames far ahead share little with anything the map
  holds unless the newest frames are uploaded (:func:`predict_frames`).

:func:`planning_world` lays the map's keyframes, the slot's frames and the predicted frames out
as the frame instances of a :class:`~twinslam.policies.world_model.MapManagementEnv` standing at the
slot; :class:`LiveMpc` hands that world to the simulator's planner each slot and translates
its answer back to frame ids. Weights are shared point counts as the edge's own planner counts
them, and a frame is lost by the edge's rule (fewer than ``MIN_INLIERS`` map points shared).
Deciding takes time the device waits for (the upload request goes out after it): at the edge
the later slots are planned exactly only on small instances (:data:`LIVE_MAX_STATES`).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import numpy as np

from edge_mapper.slot_planner import FrameObservations, SlotView
from twinslam.covisibility.dataset import CovisibilityDataset
from twinslam.policies.actions import MapAction, SlotObservation
from twinslam.policies.delayed import DelayedPolicy
from twinslam.policies.mpc import MpcConfig, MpcPlanner
from twinslam.policies.protocol import MapPolicy
from twinslam.policies.world_model import MapManagementEnv, SimConfig
from twinslam.rigid_motion import pose_of, twist_of
from twinslam.slam.camera import Camera
from twinslam.slam.projection_matching import visible_points
from twinslam.slot_protocol.lost_frame_rule import MIN_INLIERS
from twinslam.slot_protocol.map_entry import UPLOADED

#: farther than this a map point is taken to be out of an RGB-D camera's view (7-Scenes' and
#: TUM's Kinect-class sensors give depth to ~4-5 m)
MAX_DEPTH_M = 6.0
#: maps (and actions from a map) of a later slot planned exactly at the edge, unless the
#: policy's states= option says otherwise: the simulator's default (2 000) took up to 2 s a
#: slot on 60-frame slots, and LFF's decisions handed back 300 ms late left the device 17-18
#: more frames untracked a run (docs/results/planning.md, "`mpc` live"); above it the later
#: slots are the base policies' roll-outs
LIVE_MAX_STATES = 64
#: a predicted frame sees what the nearest view saw, nearest by distance and turn: a view
#: this many metres away counts as far as one turned this many degrees
NEAR_M, NEAR_DEG = 0.5, 30.0


def extrapolate(poses: Sequence[np.ndarray], positions: Sequence[int], ahead: Sequence[int]
                ) -> list[np.ndarray]:
    """Camera-to-map poses ``ahead`` frames after the last of ``poses`` (taken at frame
    ``positions`` of the slot): the rigid motion from the first pose to the last, spread
    evenly over the frames between them (a screw motion: the twist of
    :mod:`twinslam.rigid_motion`, SE(3)'s logarithm), continued
    at constant velocity in the camera's frame. One pose: the camera stands still."""
    last = np.asarray(poses[-1], dtype=np.float64)
    if len(poses) < 2 or positions[-1] == positions[0]:
        return [last.copy() for _ in ahead]
    relative = np.linalg.inv(np.asarray(poses[0], dtype=np.float64)) @ last
    twist = twist_of(relative) / (positions[-1] - positions[0])       # per frame
    return [last @ pose_of(twist * n) for n in ahead]


def visible_mask(positions: np.ndarray, pose: np.ndarray, camera: Camera,
                 max_depth_m: float = MAX_DEPTH_M) -> np.ndarray:
    """Which of the map points at ``positions`` (N×3, map frame) project into the image of
    ``camera`` at ``pose`` (camera-to-map), in front of it and nearer than ``max_depth_m``, as
    a mask: the front end's visibility test
    (:func:`twinslam.slam.projection_matching.visible_points`, which answers the ids and
    pixels of the active points; one kernel for the device, the edge's mapping, its restores
    and its planner)."""
    mask = np.zeros(len(positions), dtype=bool)
    if positions.size == 0:
        return mask
    ids, _ = visible_points(np.asarray(positions, dtype=np.float64),
                            np.ones(len(positions), dtype=bool), pose, camera.intrinsics,
                            camera.shape, (1e-3, max_depth_m))
    mask[ids] = True
    return mask


def predict_frames(view: SlotView, slots: int, max_depth_m: float = MAX_DEPTH_M
                   ) -> list[np.ndarray]:
    """The point keys of each frame of the next ``slots`` slots (as many frames a slot as
    this one), as the module docstring predicts them. Without a tracked frame's pose to go
    by (or before the first keyframe brought the intrinsics), the next frames see what the
    slot's last frame saw."""
    frames, n = view.frames, len(view.frames)
    posed = [(i, f) for i, f in enumerate(frames) if f.tracked and f.pose is not None]
    if not posed or not view.camera.known:
        last = view.points_of(frames[-1].frame_id)
        return [last.copy() for _ in range(slots * n)]
    points = view.keyframe_map.points
    views = _viewpoints(view, [f for _, f in posed])
    centres = np.array([p[:3, 3] for p, _ in views])
    axes = np.array([p[:3, 2] for p, _ in views])
    i_last = posed[-1][0]
    ahead = [n - i_last + j for j in range(slots * n)]       # frames after the last posed
    poses = extrapolate([f.pose for _, f in posed if f.pose is not None],
                        [i for i, _ in posed], ahead)
    decay = overlap_decay([view.points_of(f.frame_id) for _, f in posed])
    #: per view: its map points still in the map, and where they are (gathered once a view)
    located: dict[int, tuple[np.ndarray, np.ndarray]] = {}
    out = []
    for offset, pose in zip(ahead, poses, strict=True):
        distance = np.linalg.norm(centres - pose[:3, 3], axis=1)
        turned = np.degrees(np.arccos(np.clip(axes @ pose[:3, 2], -1.0, 1.0)))
        nearest = int(np.argmin(distance / NEAR_M + turned / NEAR_DEG))
        seen = views[nearest][1]
        if nearest not in located:
            mapped = np.array([p for p in seen[seen >= 0].tolist() if p in points],
                              dtype=np.int64)
            located[nearest] = (mapped, view.keyframe_map.positions_of(mapped))
        mapped, positions = located[nearest]
        kept = visible_mask(positions, pose, view.camera, max_depth_m)
        share = float(kept.sum()) / max(1, int(np.count_nonzero(seen >= 0)))
        tracks = seen[seen < 0]                    # no 3-D position yet: kept in the share
        keys = np.concatenate([mapped[kept], _thinned(tracks, share)])
        out.append(np.sort(_thinned(keys, decay(offset))))
    return out


def overlap_decay(sets: Sequence[np.ndarray]) -> Callable[[int], float]:
    """ρ(Δ): the share of the points a frame Δ frames after the slot's last one still sees,
    relative to the next frame, as the slot's frames (``sets``, capture order) show it:
    exp(-(Δ-1)/τ), τ fitted to the slot's mean overlaps at Δ = 1, 2, 4, … up to half the
    slot (8 frame pairs each). Frames share ever fewer points as the camera moves on; the
    planner's next frames do the same. (Relative to Δ = 1: a single frame re-detects only
    about half of its neighbour's features, but it matches the map's points all the same.)"""
    n = len(sets)
    deltas = [d for d in (2 ** i for i in range(12)) if d <= max(1, n // 2) and d < n]
    means = np.array([np.mean([np.intersect1d(sets[i], sets[i + d], assume_unique=True).size
                               / max(1, sets[i].size)
                               for i in np.linspace(0, n - d - 1, min(n - d, 8)).astype(int)])
                      for d in deltas])
    ok = means > 0
    if ok.sum() < 2:                           # too few frames to tell: the points persist
        return lambda offset: 1.0
    x = np.array(deltas, dtype=np.float64)[ok] - 1
    slope = min(0.0, float(np.polyfit(x, np.log(means[ok]), 1)[0]))
    return lambda offset: math.exp(slope * max(0, offset - 1))


def _thinned(keys: np.ndarray, share: float) -> np.ndarray:
    """The ``share`` of ``keys`` that a fixed hash ranks first: the same points drop out of
    every frame that thins the same set, the ones a smaller share keeps within a larger's."""
    if share >= 1.0 or keys.size == 0:
        return keys
    rank = np.argsort((keys.astype(np.uint64) * np.uint64(0x9E3779B97F4A7C15)) >> np.uint64(11),
                      kind="stable")
    return keys[rank[:round(share * keys.size)]]


def _viewpoints(view: SlotView, posed: list[FrameObservations]
                ) -> list[tuple[np.ndarray, np.ndarray]]:
    """(camera-to-map pose, point keys) of every view the edge knows: its keyframes and the
    slot's tracked frames."""
    kfs = view.keyframe_map.keyframes
    out = [(kfs[k].pose, view.points_of(k)) for k in view.keyframe_map.keyframe_ids()]
    return out + [(np.asarray(f.pose), view.points_of(f.frame_id)) for f in posed]


class InstanceStream:
    """Frame instance → row of the planning world's dataset: the map's K keyframes are
    instances 0 … K-1 (rows 0 … K-1); slot ``slot``'s n frames and the predicted slots after
    it follow, n instances a slot, in rows K, K+1, … (an instance past the last row reads the
    last row). A lookup table: the planner asks thousands of times a slot."""

    def __init__(self, keyframes: int, slot: int, slot_frames: int, rows: int) -> None:
        instances = np.arange(max(keyframes, (slot + 1) * slot_frames + rows))
        later = keyframes + instances - slot * slot_frames
        self._table = np.where(instances < keyframes, instances,
                               np.clip(later, keyframes, rows - 1))

    def dataset_index(self, instance: np.ndarray | list[int] | int) -> np.ndarray:
        idx = np.asarray(instance, dtype=np.int64)
        return self._table[np.minimum(idx, self._table.size - 1)]


@dataclass
class PlanningWorld:
    """A world standing at the slot, and the way between its instances and frame ids."""

    env: MapManagementEnv
    instance_of: dict[int, int]
    frame_of: dict[int, int]

    def action(self, action: MapAction) -> MapAction:
        """A world action as the edge's frame ids."""
        return MapAction([self.frame_of[i] for i in action.upload],
                         [self.frame_of[i] for i in action.evict])


def planning_world(view: SlotView, obs: SlotObservation, horizon: int,
                   max_depth_m: float = MAX_DEPTH_M) -> PlanningWorld:
    """The map, the slot's frames and ``horizon`` predicted slots as a
    :class:`MapManagementEnv` standing at the slot (module docstring); its observation has the
    slot's sizes (Theorem 1's, from the same V_max, rate and map)."""
    n, k = len(view.frames), len(view.map_ids)
    slot = k // n + 1                          # the map's instances all lie before the slot
    sets = ([view.points_of(x) for x in view.map_ids]
            + [view.points_of(f.frame_id) for f in view.frames]
            + predict_frames(view, horizon, max_depth_m))
    cfg = view.config
    config = SimConfig(vmax=cfg.vmax, slot_frames=n, alpha_mbit=cfg.alpha_mbit,
                       d_req_s=cfg.d_req_s, slots=slot + horizon, log_det_pi=cfg.log_det_pi,
                       min_shared=MIN_INLIERS)
    instance_of = {x: i for i, x in enumerate(view.map_ids)}
    instance_of.update({f.frame_id: slot * n + j for j, f in enumerate(view.frames)})
    now = (obs.rate_state, obs.rate_mbps)
    env = MapManagementEnv.standing_at(
        CovisibilityDataset.from_sets(sets, source="edge planning world"), config,
        obs.n_states, slot, [instance_of[x] for x in obs.map_frames],
        [instance_of[x] for x in obs.candidates], [now] * (slot + horizon + 1),
        InstanceStream(k, slot, n, len(sets)),
        # the map's entry order as slots before this one: the world's uploads come after
        {instance_of[x]: (slot - len(obs.map_frames) + i, UPLOADED)
         for i, x in enumerate(obs.entry_order())})
    seen = env.observation()
    if (seen.n_upload, seen.n_evict) != (obs.n_upload, obs.n_evict):
        raise ValueError(f"slot {obs.slot}: the planning world sizes the slot "
                         f"{seen.n_upload}/{seen.n_evict}, the edge "
                         f"{obs.n_upload}/{obs.n_evict}")
    return PlanningWorld(env, instance_of, {i: x for x, i in instance_of.items()})


def live_refused(config: MpcConfig) -> str | None:
    """Why ``mpc`` with these options cannot run at the edge (None: it can)."""
    if config.frames != "motion":
        return (f"mpc frames={config.frames} is simulator-only: live, the next frames are "
                "predicted from the map in the camera's extrapolated frustum (frames=motion)")
    if config.rates == "oracle":
        return "mpc rates=oracle is simulator-only: the edge does not know future rates"
    return None


class LiveMpc:
    """``mpc`` at the edge: each slot the planner plans in :func:`planning_world`."""

    def __init__(self, planner: MpcPlanner, max_depth_m: float = MAX_DEPTH_M) -> None:
        reason = live_refused(planner.config)
        if reason:
            raise ValueError(reason)
        self.name = planner.name
        # the world's future frames are the prediction already: the planner takes them as
        # they are instead of extrapolating through the world's (made-up) instance order;
        # and a decision delays the slot's uploads, so the later slots are planned exactly
        # only on small instances unless states= says otherwise
        config = replace(planner.config, frames="oracle")
        if config.max_states == MpcConfig().max_states:
            config = replace(config, max_states=LIVE_MAX_STATES)
        self.planner = planner.with_config(config)
        self.max_depth_m = max_depth_m
        self._view: SlotView | None = None

    def reset(self, seed: int | None = None) -> None:
        self.planner.reset(seed)

    def see_slot(self, view: SlotView) -> None:
        """What the next ``decide`` plans with (the slot planner calls it)."""
        self._view = view

    def decide(self, obs: SlotObservation) -> MapAction:
        view, self._view = self._view, None
        if view is None:
            raise RuntimeError("mpc at the edge needs the slot's map and frames: the slot "
                               "planner hands them over (see_slot) before each decision")
        world = planning_world(view, obs, self.planner.config.horizon, self.max_depth_m)
        self.planner.attach(world.env)
        seen = replace(world.env.observation(), slot=obs.slot,
                       rate_history=list(obs.rate_history))
        return world.action(self.planner.decide(seen))


def at_the_edge(policy: MapPolicy) -> MapPolicy:
    """``policy`` as the edge runs it: ``mpc`` plans in a world built from the live map (also
    under a delay); any other, and one already made for the edge, as it is."""
    if isinstance(policy, MpcPlanner):
        return LiveMpc(policy)
    if isinstance(policy, DelayedPolicy):
        inner = at_the_edge(policy.policy)
        return policy if inner is policy.policy else DelayedPolicy(inner, policy.seconds)
    return policy
