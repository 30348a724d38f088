"""The world model: a gymnasium-style environment where one ``step`` is one slot of map
management (docs/architecture.md §4). The simulator scores policies in it, the learned policy
trains in it, ``mpc`` imagines its futures in it and the edge builds one from its live map.

At slot k the agent sees the map V^e_k, the slot's frames F_k and the rate d_k, and answers
with U_k ⊆ F_k and C_k ⊆ V^e_k ∪ U_k of Theorem 1's sizes. The environment applies the update
(eq. 3), draws F_{k+1} and d_{k+1}, and returns r_k = -υ_k (eq. 8, a lost frame scoring u = 0).

Which next-slot frame is lost follows what the live device lives by
(:mod:`twinslam.slot_protocol.lost_frame_rule`): a frame that shares fewer than ``min_shared`` map
points with the map it is tracked against is lost; the first ``lag_frames`` frames of
slot k + 1 are tracked against V^e_k (the update of slot k is still on its way), the rest
against V^e_{k+1}; and a lost frame, having no pose, is not among the next slot's upload
candidates. With ``min_shared`` 1 and ``update_lag_frames`` 0 this is the paper's eq. 8
exactly (``SimConfig.paper_rule``).

With an archive (``SimConfig.archive_keyframes``) the environment is the edge of the
archive: an evicted keyframe is kept, up to that many, the least recently useful leaving
first, and a policy may bring up to ``restore_keyframes`` of them back a slot
(``MapAction.restore``, over the downlink: no uplink time), evicting one more map keyframe for
each that does not fit under V_max. Without one (the default) it is the paper's edge, where
what is evicted is gone.

Frames come from a covisibility dataset, read forwards then backwards (a walk that turns
around) so that episodes can be longer than the recording; every frame *instance* has its own
id, and two instances of the same recorded frame share all their points.
"""

from __future__ import annotations

import copy
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from twinslam.covisibility.dataset import CovisibilityDataset
from twinslam.covisibility.map_points import MapPointCounts
from twinslam.policies.actions import MapAction, SlotObservation, check_map_action
from twinslam.slot_protocol import table1
from twinslam.slot_protocol.lost_frame_rule import MIN_SHARED_POINTS, update_lag_frames
from twinslam.slot_protocol.map_entry import RESTORED, UPLOADED, entry_order
from twinslam.slot_protocol.slot_settings import SlotSettings
from twinslam.uncertainty import laplacian_kernels as kernels
from twinslam.uncertainty.laplacian_factorization import PIVOT_RTOL
from twinslam.uncertainty.map_uncertainty import (
    SlotUncertainty,
    lost_frames,
    needs_map,
    slot_uncertainty_from_scores,
    theorem1_cardinalities,
    waited_after,
)
from twinslam.uplink.channels import MarkovChannel, TraceChannel


@dataclass(frozen=True)
class SimConfig(SlotSettings):
    """The slot protocol's settings (:class:`~twinslam.slot_protocol.slot_settings.
    SlotSettings`: V_max, α, D_req, the progress rule — the edge's too), the slot's length F
    and the episode's; paper Table I defaults."""

    slot_frames: int = table1.SLOT_FRAMES
    slots: int = 200
    log_det_pi: float = 0.0
    history: int = 8            #: length τ+1 of the rate history in observations
    #: a next-slot frame sharing fewer map points with its map is lost (1: the paper's rule)
    min_shared: int = MIN_SHARED_POINTS
    #: the first this many frames of a slot are tracked against the map before the update
    #: (None: D_req plus the edge's measured delay, at 30 Hz; 0: the paper's timeline)
    update_lag_frames: int | None = None
    #: the dataset frame every episode starts at (None: a random one per seed); 0 plays the
    #: dataset forward then back from its first frame, as the player's forward_backward order
    start: int | None = None
    #: recorded frames a device walks per camera frame: 1 as recorded, 2 twice as fast, 0.5
    #: half as fast (each frame seen twice), 0 standing still (many devices)
    speed: float = 1.0
    #: evicted keyframes the edge keeps (0: none, the paper's edge)
    archive_keyframes: int = 0
    #: archived keyframes a policy may bring back a slot (0: none)
    restore_keyframes: int = 0

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.slot_frames < 1:
            raise ValueError(f"a slot needs at least one frame, got {self.slot_frames}")
        if self.archive_keyframes < 0 or self.restore_keyframes < 0:
            raise ValueError("archive and restore keyframes must be >= 0, got "
                             f"{self.archive_keyframes} and {self.restore_keyframes}")
        if self.restore_keyframes and not self.archive_keyframes:
            raise ValueError(f"restoring {self.restore_keyframes} keyframes a slot needs an "
                             "archive to restore from (archive keyframes > 0)")

    @classmethod
    def paper_rule(cls, **kwargs: Any) -> SimConfig:
        """The paper's scoring: lost only when no map point is shared, the map update there at
        the slot's first frame (toy worlds of a few points a frame, and the paper's own
        numbers, are scored so)."""
        return cls(min_shared=1, update_lag_frames=0, **{"progress": False, **kwargs})

    @property
    def slot_seconds(self) -> float:
        """The deadline the progress rule stretches to: the slot's length (0: rule off)."""
        return self.deadline_s(self.slot_frames)

    @property
    def lag_frames(self) -> int:
        """The frames of a slot tracked with the map before the last update."""
        if self.update_lag_frames is not None:
            return self.update_lag_frames
        return update_lag_frames(self.d_req_s, table1.FRAME_RATE_HZ)


#: what :meth:`MapManagementEnv.snapshot` returns: (map frames, map weights, slot, upload
#: candidates, archive, Mbit the uplink carried while the device waited for a map, when each
#: map frame entered the map as (slot, UPLOADED | RESTORED)); the future depends on all of
#: them but the weights
Snapshot = tuple[list[int], np.ndarray, int, list[int], list[int], float,
                 dict[int, tuple[int, int]]]


def state_key(snap: Snapshot) -> tuple[Any, ...]:
    """What two snapshots must share to have the same future: the map, the candidates, the
    archive and the uplink waited for (a search merges the states with one key). When the
    map's frames entered it is left out: only a rule's choice of the oldest reads it, never
    the searches that merge states."""
    return tuple(snap[0]), tuple(snap[3]), tuple(snap[4]), snap[5]


class FrameStream:
    """Maps frame-instance ids to dataset frames, reading the dataset forth and back."""

    def __init__(self, dataset: CovisibilityDataset, start: int = 0, horizon: int = 0,
                 speed: float = 1.0) -> None:
        if not np.isfinite(speed) or speed < 0:
            raise ValueError(f"a walking speed must be >= 0, got {speed}")
        self.n = dataset.n_frames
        self.start, self.speed = start, speed
        #: dataset index of instances 0..horizon-1, looked up instead of recomputed per query
        self._table = self._compute(np.arange(horizon))

    def _compute(self, instance: np.ndarray) -> np.ndarray:
        t = (instance if self.speed == 1.0
             else np.floor(instance * self.speed).astype(np.int64)) + self.start
        period = 2 * (self.n - 1) if self.n > 1 else 1
        phase = t % period
        return np.where(phase < self.n, phase, period - phase)

    def dataset_index(self, instance: np.ndarray | list[int] | int) -> np.ndarray:
        idx = np.asarray(instance, dtype=np.int64)
        try:
            return self._table[idx]
        except IndexError:                 # beyond the episode's horizon
            return self._compute(idx)


class PredictedStream:
    """The frames as the planner imagines them: the instances seen so far as they were, the
    later ones by ``mode`` (module docstring) from the last slot seen."""

    def __init__(self, base: FrameStream, seen: int, slot_frames: int, n_frames: int,
                 mode: str) -> None:
        self.base, self.seen, self.slot_frames, self.n, self.mode = (
            base, seen, slot_frames, n_frames, mode)
        first = int(base.dataset_index(max(0, seen - slot_frames)))
        self.last = int(base.dataset_index(seen - 1))
        #: frames moved per instance across the last slot seen (signed: backwards too)
        self.velocity = (self.last - first) / max(1, slot_frames - 1)

    def dataset_index(self, instance: np.ndarray | list[int] | int) -> np.ndarray:
        idx = np.asarray(instance, dtype=np.int64)
        future = idx >= self.seen
        if self.mode == "persistence":
            src = np.where(future, self.seen - self.slot_frames
                           + (idx - self.seen) % self.slot_frames, idx)
            return self.base.dataset_index(src)
        out = self.base.dataset_index(np.where(future, self.seen - 1, idx))
        t = np.rint(self.last + self.velocity * (idx - (self.seen - 1))).astype(np.int64)
        period = max(1, 2 * (self.n - 1))
        phase = t % period
        reflected = np.where(phase < self.n, phase, period - phase)   # back at the ends
        return np.where(future, reflected, out)


class MapManagementEnv:
    """Gym-style: ``reset(seed) -> (obs, info)``;
    ``step(action) -> (obs, reward, terminated, truncated, info)``."""

    def __init__(self, dataset: CovisibilityDataset, channel: MarkovChannel | TraceChannel,
                 config: SimConfig | None = None) -> None:
        self.dataset = dataset
        self.channel = channel
        self.config = config or SimConfig()
        if dataset.n_frames < 2:
            raise ValueError("a covisibility dataset needs at least two frames")
        self.stream = FrameStream(dataset)
        self._map: list[int] = []
        self._map_w = np.zeros((0, 0))
        self._slot = 0
        #: when each map frame entered the map, (slot, UPLOADED | RESTORED): a rule's "oldest"
        #: (:mod:`twinslam.slot_protocol.map_entry`); a frame not in it is older than all
        self._entered: dict[int, tuple[int, int]] = {}
        #: the observation last handed out, valid until the map or the slot changes
        self._last_obs: SlotObservation | None = None
        self._plan: list[tuple[int, float]] = []   #: (state, rate) of every slot of the episode
        #: the current slot's frames the device tracked: the upload candidates
        self._uploadable: list[int] = []
        #: evicted keyframes the edge still holds, least recently useful first
        self._archive: list[int] = []
        #: Mbit the uplink carried while the device, needing a map, waited for an upload
        #: (:func:`~twinslam.uncertainty.map_uncertainty.waited_after`, as the edge's planner)
        self._waited = 0.0
        #: the map's points per point, moved with the map (the device's rule only)
        self._points: MapPointCounts | None = None
        #: the last map scored: (its key, its factorisation, its weights). A slot's first
        #: frames are scored against the map the previous slot's frames were, so one
        #: factorisation serves both
        self._factor: tuple[tuple[int, bytes], tuple[Any, ...], np.ndarray] | None = None

    @classmethod
    def standing_at(cls, dataset: CovisibilityDataset, config: SimConfig, n_states: int,
                    slot: int, map_frames: Sequence[int], uploadable: Sequence[int],
                    plan: Sequence[tuple[int, float]], stream: Any,
                    entered: Mapping[int, tuple[int, int]] | None = None
                    ) -> MapManagementEnv:
        """An environment standing at slot ``slot`` that nobody walked to: a world a planner
        builds from what it knows (the edge's live map, its slot's frames and the frames it
        predicts) instead of one that ``reset`` drew. ``map_frames`` and ``uploadable`` are
        frame instances, ``stream`` maps instances to ``dataset`` rows (anything with
        ``dataset_index``), ``plan`` is (state, rate) of slots 0 … ``config.slots``,
        ``entered`` when each map frame entered the map (None: all before the others)."""
        if len(plan) <= config.slots or not 0 <= slot < config.slots:
            raise ValueError(f"slot {slot} with a plan of {len(plan)} slots: the plan must "
                             f"cover slots 0 … {config.slots} and the slot lie before the last")
        env = cls(dataset, MarkovChannel(np.zeros(n_states)), config)
        env.stream, env._slot, env._plan = stream, int(slot), list(plan)
        env._map, env._uploadable = list(map_frames), list(uploadable)
        env._map_w = env.weights(env._map, env._map)
        env._entered = dict(entered or {})
        return env

    # -- weights -----------------------------------------------------------------------------

    def weights(self, a: list[int], b: list[int]) -> np.ndarray:
        """Covisibility weights between frame instances; an instance has weight 0 to itself."""
        block = self.dataset.weights(self.stream.dataset_index(a), self.stream.dataset_index(b))
        if len(a) and len(b) and not set(a).isdisjoint(b):
            at = {x: j for j, x in enumerate(b)}
            for i, x in enumerate(a):
                if x in at:
                    block[i, at[x]] = 0.0
        return block

    def slot_frames(self, slot: int) -> list[int]:
        f = self.config.slot_frames
        return list(range(slot * f, (slot + 1) * f))

    # -- gym interface -----------------------------------------------------------------------

    def reset(self, seed: int | None = None) -> tuple[SlotObservation, dict[str, Any]]:
        rng = np.random.default_rng(seed)
        start = int(rng.integers(self.dataset.n_frames))
        if self.config.start is not None:
            if not 0 <= self.config.start < self.dataset.n_frames:
                raise ValueError(f"start frame {self.config.start} is not one of the dataset's "
                                 f"{self.dataset.n_frames}")
            start = self.config.start
        self.stream = FrameStream(self.dataset, start=start,
                                  horizon=(self.config.slots + 2) * self.config.slot_frames,
                                  speed=self.config.speed)
        self.channel.reset(seed)
        self._map, self._map_w, self._slot = [], np.zeros((0, 0)), 0
        self._archive, self._waited, self._entered = [], 0.0, {}
        self._uploadable = self.slot_frames(0)       # tracked on the device's start-up map
        # The whole episode's rates are drawn up front: the agent still sees them one slot at a
        # time, but a clairvoyant planner can read ahead and snapshots stay exact.
        self._plan = [self.channel.step() for _ in range(self.config.slots + 1)]
        self._last_obs = self._observation()
        return self._last_obs, {}

    @property
    def rate_plan(self) -> list[tuple[int, float]]:
        """(state, rate) of every slot of the episode; for the clairvoyant references only."""
        return list(self._plan)

    def _observation(self) -> SlotObservation:
        state, rate = self._plan[self._slot]
        cand = list(self._uploadable)
        n_up, n_ev = theorem1_cardinalities(rate, self.config.alpha_mbit, self.config.d_req_s,
                                            self.config.vmax, len(self._map), len(cand),
                                            self.config.slot_seconds, self._waited)
        hist = [s for s, _ in self._plan[max(0, self._slot - self.config.history + 1):
                                         self._slot + 1]]
        n_restore = self.config.restore_keyframes if self.config.archive_keyframes > 0 else 0
        entered = entry_order(self._map, self._entered)
        return SlotObservation(self._slot, list(self._map), cand, n_up, n_ev, rate, state, hist,
                               self.channel.n_states, self.weights, list(self._archive),
                               n_restore, self.config.vmax, entered)

    def observation(self) -> SlotObservation:
        """What the agent sees now (after ``reset``, ``step`` or ``restore``)."""
        if self._last_obs is None:
            self._last_obs = self._observation()
        return self._last_obs

    def set_vmax(self, vmax: int) -> None:
        """V_max from the current slot's decision on: an edge that splits one keyframe budget
        between devices changes each device's share slot by slot; a smaller one
        evicts the excess at once (Theorem 1's |C_k|)."""
        if vmax < 0:
            raise ValueError(f"V_max must be >= 0, got {vmax}")
        if vmax != self.config.vmax:
            self.config = replace(self.config, vmax=int(vmax))
            self._last_obs = None

    def set_rate(self, rate_mbps: float) -> None:
        """The current slot's rate instead of the channel's (a device's share of a cell that
        several devices' uplinks share); its state stays the channel's."""
        if not np.isfinite(rate_mbps) or rate_mbps < 0:
            raise ValueError(f"a rate must be finite and >= 0, got {rate_mbps}")
        state, _ = self._plan[self._slot]
        self._plan[self._slot] = (state, float(rate_mbps))
        self._last_obs = None

    def check_action(self, obs: SlotObservation, action: MapAction) -> None:
        """Refuse an action that breaks slot ``obs.slot``'s constraints. Frame sets come from
        the environment, not from ``obs``, so a policy that edits its observation cannot
        smuggle frames in (a lost frame among them)."""
        check_map_action(obs.slot, obs.n_upload, obs.n_evict, set(self._uploadable), self._map,
                         action, set(self._archive), obs.n_restore, self.config.vmax)

    def apply(self, action: MapAction, *, weights: bool = True) -> None:
        """V^e_{k+1} = (U_k ∪ V^e_k) \\ C_k, keeping capture order (oldest = anchor first).

        ``weights=False`` leaves the map's weight matrix for the caller to set (``step`` on a
        dense dataset gathers it in the same kernel call as the reward). Restored keyframes
        leave the archive, evicted ones join it."""
        self._last_obs = None
        self._archive_update(action)
        for f in action.evict:
            self._entered.pop(f, None)
        for how, frames in ((UPLOADED, action.upload), (RESTORED, action.restore)):
            for f in frames:
                if f not in action.evict:
                    self._entered[f] = (self._slot, how)
        if not weights:
            self._map = sorted(set(self._map).union(action.upload, action.restore)
                               .difference(action.evict))
            return
        evict = set(action.evict)
        src = np.array([i for i, f in enumerate(self._map) if f not in evict], dtype=np.int64)
        kept = [self._map[i] for i in src]
        new = sorted(f for f in [*action.upload, *action.restore] if f not in evict)
        merged = sorted(kept + new)
        if self.dataset.dense:               # a gather of the whole block is the cheapest
            ds = self.stream.dataset_index(merged)
            self._map, self._map_w = merged, self.dataset.weights(ds, ds)
            np.fill_diagonal(self._map_w, 0.0)   # an instance shares no edge with itself
            return
        # Sparse products are not: reuse the old rows, query only the new pairs.
        w = np.zeros((len(merged), len(merged)))
        if merged == kept + new:          # uploads are newer than the map: blocks, no scatter
            w[:src.size, :src.size] = self._map_w.take(src, axis=0).take(src, axis=1)
            new_pos = np.arange(src.size, len(merged))
        else:
            at = {f: i for i, f in enumerate(merged)}
            old_pos = np.array([at[f] for f in kept], dtype=np.int64)
            w[np.ix_(old_pos, old_pos)] = self._map_w.take(src, axis=0).take(src, axis=1)
            new_pos = np.array([at[f] for f in new], dtype=np.int64)
        if new:
            block = self.weights(new, merged)
            w[new_pos, :] = block
            w[:, new_pos] = block.T
        self._map, self._map_w = merged, w

    def _archive_update(self, action: MapAction) -> None:
        """The archive after ``action``: its restores leave, its evictions join as the most
        recently useful, the least recently useful leave beyond ``archive_keyframes``."""
        keep = self.config.archive_keyframes
        if keep <= 0:
            return
        back = set(action.restore)
        archive = [f for f in self._archive if f not in back] + sorted(action.evict)
        self._archive = archive[max(0, len(archive) - keep):]

    def step(self, action: MapAction) -> tuple[SlotObservation, float, bool, bool, dict[str, Any]]:
        obs = self.observation()
        self.check_action(obs, action)
        uploadable = set(self._uploadable)
        self._waited = waited_after(
            obs.n_upload, obs.rate_mbps, self.config.slot_seconds, self._waited,
            needs_map(f not in uploadable for f in self.slot_frames(self._slot)))
        before, before_w = self._map, self._map_w
        dense = self.dataset.dense
        self.apply(action, weights=not dense)
        self._slot += 1
        f = self.config.slot_frames
        frames = np.arange(self._slot * f, (self._slot + 1) * f)
        # the update of the slot just decided reaches the device late: its first frames are
        # still tracked against the map before (none before the first update: start-up map)
        lag = min(self.config.lag_frames, f) if before else 0
        early = (self._score(before, before_w, frames[:lag])[:2] if lag
                 else (None, np.zeros(0, dtype=bool)))
        late, lost_late, new_w = self._score(self._map, None if dense else self._map_w,
                                             frames[lag:])
        self._map_w = new_w
        slot_u = late if early[0] is None else SlotUncertainty(
            early[0].tracked_sum + late.tracked_sum, early[0].n_tracked + late.n_tracked,
            early[0].n_frames + late.n_frames, late.map_uncertainty)
        lost = np.concatenate([early[1], lost_late])
        self._uploadable = frames[~lost].tolist()
        info = {"uncertainty": slot_u, "map_size": len(self._map),
                "map_uncertainty": slot_u.map_uncertainty, "lost": lost,
                "restored": len(action.restore)}
        truncated = self._slot >= self.config.slots
        self._last_obs = self._observation()
        return self._last_obs, slot_u.reward, False, truncated, info

    def _score(self, map_frames: list[int], map_w: np.ndarray | None, frames: np.ndarray
               ) -> tuple[SlotUncertainty, np.ndarray, np.ndarray]:
        """(υ over ``frames``, which of them are lost, the map's weights) against the map of
        ``map_frames`` (weights ``map_w``, or gathered here when the dataset is dense)."""
        map_idx = self.stream.dataset_index(map_frames)
        frame_idx = self.stream.dataset_index(frames)
        n = len(map_frames)
        if n == 0:
            log_tau = np.full(frames.size, -np.inf)
            return (slot_uncertainty_from_scores(0, 0, -np.inf, log_tau, self.config.log_det_pi),
                    np.ones(frames.size, dtype=bool), np.zeros((0, 0)))
        # the weights, and so the factorisation, are a function of the dataset frames alone
        key = (id(self.dataset), map_idx.tobytes())
        if self._factor is not None and self._factor[0] == key:
            factor, map_w = self._factor[1], self._factor[2]
            inv, pos, comp, n_comp, log_det = factor
            block = np.ascontiguousarray(self.dataset.weights(frame_idx, map_idx))
            log_tau = kernels.augmented_log_taus(inv, pos, comp, n_comp, block,
                                                 np.arange(frame_idx.size), None, log_det,
                                                 0.0, 0.0, PIVOT_RTOL)
        else:
            if map_w is None:                   # dense: map weights and scores in one call
                map_w, inv, pos, comp, n_comp, log_det, log_tau = \
                    kernels.gathered_factored_scores(self.dataset.dense_weights, map_idx,
                                                     frame_idx, PIVOT_RTOL)
            else:
                block = np.ascontiguousarray(self.dataset.weights(frame_idx, map_idx))
                inv, pos, comp, n_comp, log_det, log_tau = kernels.factored_slot_scores(
                    map_w, block, PIVOT_RTOL)
            self._factor = (key, (inv, pos, comp, n_comp, log_det), map_w)
        trackable = None
        if self.config.min_shared > 1:
            self._points = self._points or MapPointCounts(self.dataset)
            trackable = self._points.reaching(map_idx, frame_idx, self.config.min_shared)
        slot_u = slot_uncertainty_from_scores(n, n_comp, log_det, log_tau,
                                              self.config.log_det_pi, trackable)
        return slot_u, lost_frames(log_tau, trackable), map_w

    def emulate(self, before: Snapshot, action: MapAction,
                next_rate: tuple[int, float]) -> tuple[SlotObservation, float, dict[str, Any]]:
        """What ``step(action)`` from the snapshot ``before`` would have returned had slot
        k + 1's rate been ``next_rate`` = (state, Mbit/s): an artificial experience (paper
        eq. 23: emulated map update, its reward, the next state with the sampled rate). The
        environment is left exactly as it was."""
        now, last_obs = self.snapshot(), self._last_obs
        k = before[2]
        if not 0 <= k < self.config.slots:
            raise ValueError(f"slot {k} is outside the episode (0..{self.config.slots - 1})")
        real_next = self._plan[k + 1]
        self.restore(before)
        self._plan[k + 1] = (int(next_rate[0]), float(next_rate[1]))
        try:
            obs, reward, _term, _trunc, info = self.step(action)
        finally:
            self._plan[k + 1] = real_next
            self.restore(now)
            self._last_obs = last_obs
        return obs, reward, info

    # -- planning support (the clairvoyant references, the causal planner) ------------------

    def imagine(self, rates: Sequence[tuple[int, float]] | None = None,
                stream: Any = None) -> MapManagementEnv:
        """A copy of this environment at its current state whose future is the one given:
        (state, rate) of the slots after this one (None: the true ones) and the stream that
        maps frame instances to the dataset (None: the true one; anything with
        ``dataset_index``). A planner steps and restores it freely; this one is untouched."""
        world = copy.copy(self)
        world._map, world._map_w = list(self._map), self._map_w.copy()
        world._uploadable = list(self._uploadable)
        world._archive = list(self._archive)
        world._entered = dict(self._entered)
        world._points, world._last_obs = None, None
        world._plan = list(self._plan)
        if rates is not None:
            for i, rate in enumerate(rates, start=self._slot + 1):
                if i < len(world._plan):
                    world._plan[i] = (int(rate[0]), float(rate[1]))
        if stream is not None:
            world.stream = stream
        return world


    def coming_view(self, slot: int) -> tuple[Any, list[int]]:
        """The next slot's frames as a causal planner predicts them at the end of ``slot``:
        the camera moving on at the velocity it had across ``slot`` (in recorded frames,
        turned back at the sequence's ends; :class:`PredictedStream` "motion", what the live
        edge's extrapolated poses are), as (a weights function that knows them, their
        instance ids)."""
        f = self.config.slot_frames
        world = self.imagine(None, PredictedStream(self.stream, (slot + 1) * f, f,
                                                   self.dataset.n_frames, "motion"))
        return world.weights, world.slot_frames(slot + 1)

    @property
    def map_frames(self) -> list[int]:
        return list(self._map)

    def snapshot(self) -> Snapshot:
        """(map frames, map weights, slot, the slot's upload candidates, the archive, the
        uplink waited for, when the map's frames entered it): all a later ``restore`` needs
        to continue exactly from here."""
        return (list(self._map), self._map_w.copy(), self._slot, list(self._uploadable),
                list(self._archive), self._waited, dict(self._entered))

    def restore(self, snap: Snapshot) -> None:
        frames, w, self._slot, uploadable, archive, self._waited, entered = snap
        self._entered = dict(entered)
        self._last_obs = None
        self._map, self._map_w = list(frames), w.copy()
        self._uploadable, self._archive = list(uploadable), list(archive)

