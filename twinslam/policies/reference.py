"""The reference plan: a clairvoyant search that every policy's score is set against.

It knows every future frame and rate and plans the whole episode, but it is a *search*, not a
bound: problem P1 has ~10¹¹–10¹⁸ action sequences per episode at the paper's sizes, and
nothing here proves the result optimal. A policy that scores below the reference has found a
plan the search missed (that is a finding about the search, not a violation). Only
:func:`~twinslam.policies.exact_optimum.exact_optimum` is the true optimum, on small instances.
No valid lower bound at full size is known to us that is tight enough to report
(docs/architecture.md §9).

Three stages, each keeping the best plan so far, so the reference is never worse than any
policy it was given:

1. **Roll-outs** of every given policy, and the plans it is handed (e.g. the learned
   policies' plans an evaluation already rolled out).
2. **Beam search**: each beam state (map after slot k) is expanded with every given policy's
   action in that state, every handed plan's action for slot k where it is valid in that state,
   and random one-frame swaps of them — with an archive, each also with the archived keyframes
   the next slot's true frames need brought back (:mod:`~twinslam.policies.restoring`:
   the restores made with the future known); states leaving the same map, candidates and
   archive are merged (the future depends on nothing else), the ``beam`` with the lowest
   accumulated υ survive.
3. **Swap local search** on the true objective: change one upload (u → u' of the same slot) or
   one eviction (c → c' of the same pool) of the best plan, carry the swap through the later
   slots (a later eviction of the frame swapped out now evicts the frame swapped in), replay
   the rest of the episode and keep the change if the total υ went down.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from twinslam.policies.actions import (
    ActionError,
    MapAction,
    SlotObservation,
    check_map_action,
)
from twinslam.policies.plan import Plan, replay, rollout
from twinslam.policies.protocol import MapPolicy
from twinslam.policies.restoring import with_restores
from twinslam.policies.rules import Adapt, LatestFrameFirst, PeriodicalUploading
from twinslam.policies.world_model import MapManagementEnv, state_key
from twinslam.uncertainty.map_uncertainty import SlotUncertainty


def rule_policies() -> list[MapPolicy]:
    return [LatestFrameFirst(), PeriodicalUploading(), Adapt()]


def swap_one(obs: SlotObservation, base: MapAction, rng: np.random.Generator) -> MapAction:
    """Swap one upload and one eviction of ``base`` at random (keeps Theorem 1's sizes and
    ``base``'s restores)."""
    up = list(base.upload)
    others = [f for f in obs.candidates if f not in up]
    if up and others:
        up[rng.integers(len(up))] = others[rng.integers(len(others))]
    pool = sorted(obs.map_frames + up)
    evict = [f for f in base.evict if f in pool]
    rest = [f for f in pool if f not in evict]
    while len(evict) < obs.evictions_with(len(base.restore)):   # an evicted upload swapped out
        evict.append(rest.pop(int(rng.integers(len(rest)))))
    if evict and rest and rng.random() < 0.5:
        evict[rng.integers(len(evict))] = rest[rng.integers(len(rest))]
    return MapAction(sorted(up), sorted(evict), list(base.restore))


def _renamed(action: MapAction, old: int, new: int) -> MapAction:
    """``action`` with frame ``old`` evicted as ``new`` (the swap carried into a later slot)."""
    return MapAction(list(action.upload), sorted(new if f == old else f for f in action.evict),
                     list(action.restore))


@dataclass
class _Beam:
    total: float
    actions: list[MapAction]
    slots: list[SlotUncertainty]
    snapshot: tuple[Any, ...]


class ReferencePlanner:
    """Roll-outs, beam search and swap local search (module docstring); ``plan`` returns the
    best plan found. ``policies`` defaults to LFF, PU and ADAPT; pass the learned policies
    being evaluated too, so the reference starts from their plans as well."""

    name = "reference"

    def __init__(self, policies: Sequence[MapPolicy] | None = None, beam: int = 8,
                 perturbations: int = 4, swap_evaluations: int = 400) -> None:
        if beam < 1 or perturbations < 0 or swap_evaluations < 0:
            raise ValueError("beam must be >= 1, perturbations and swap_evaluations >= 0")
        self.policies = list(policies) if policies is not None else rule_policies()
        if not self.policies:
            raise ValueError("the reference needs at least one policy to decide with in every "
                             "beam state")
        self.beam = beam
        self.perturbations = perturbations
        self.swap_evaluations = swap_evaluations

    def plan(self, env: MapManagementEnv, seed: int, known: Sequence[Plan] = ()) -> Plan:
        """The best plan found from ``reset(seed)``; ``known`` plans of the same episode (other
        policies' roll-outs) are starting points too."""
        plans = [rollout(env, p, seed) for p in self.policies] + list(known)
        plans.append(self._beam_search(env, seed, list(known)))
        best = min(plans, key=lambda p: p.total)
        return self._local_search(env, seed, best)

    # -- beam search --------------------------------------------------------------------------

    def _proposals(self, obs: SlotObservation, rng: np.random.Generator,
                   known: list[Plan], coming: list[int]) -> list[MapAction]:
        """The actions a beam state is expanded with; with an archive, each also with the
        archived keyframes the ``coming`` slot's true frames need brought back."""
        base = [p.decide(obs) for p in self.policies]
        for plan in known:               # a handed plan's action, where this state allows it
            a = plan.actions[obs.slot]   # (another state may have lost its frames: then not)
            try:
                check_map_action(obs.slot, obs.n_upload, obs.n_evict, obs.candidates,
                                 obs.map_frames, a, obs.archive, obs.n_restore, obs.vmax)
            except ActionError:
                continue
            base.append(a)
        extra = ([swap_one(obs, base[i % len(base)], rng) for i in range(self.perturbations)]
                 if base else [])
        if obs.n_restore > 0:            # the future known: restore for the frames to come
            extra += [with_restores(obs, MapAction(a.upload, a.evict), coming)
                      for a in base if not a.restore]
        unique: dict[tuple[Any, ...], MapAction] = {}
        for a in base + extra:
            unique[(tuple(sorted(a.upload)), tuple(sorted(a.evict)),
                    tuple(sorted(a.restore)))] = a
        return list(unique.values())

    def _beam_search(self, env: MapManagementEnv, seed: int, known: list[Plan]) -> Plan:
        rng = np.random.default_rng(seed)
        env.reset(seed)
        for p in self.policies:
            p.reset(seed)
        beams = [_Beam(0.0, [], [], env.snapshot())]
        for _slot in range(env.config.slots):
            children: dict[tuple[Any, ...], _Beam] = {}
            for b in beams:
                env.restore(b.snapshot)
                coming = env.slot_frames(_slot + 1)
                for action in self._proposals(env.observation(), rng, known, coming):
                    env.restore(b.snapshot)
                    _obs, reward, _t, _tr, info = env.step(action)
                    after = env.snapshot()
                    child = _Beam(b.total - reward, [*b.actions, action],
                                  [*b.slots, info["uncertainty"]], after)
                    key = state_key(after)
                    if key not in children or child.total < children[key].total:
                        children[key] = child
            beams = sorted(children.values(), key=lambda c: c.total)[:self.beam]
        return Plan(beams[0].actions, beams[0].slots)

    # -- swap local search --------------------------------------------------------------------

    def _local_search(self, env: MapManagementEnv, seed: int, plan: Plan) -> Plan:
        rng = np.random.default_rng(seed + 1)
        actions = list(plan.actions)
        best = replay(env, actions, seed)
        snaps, observations = self._trace(env, actions, seed)
        for _ in range(self.swap_evaluations):
            k = int(rng.integers(len(actions)))
            swapped = self._swap(observations[k], actions, k, rng)
            if swapped is None:
                continue
            env.restore(snaps[k])
            slots = list(best.slots[:k])
            try:
                for action in swapped[k:]:
                    _obs, _r, _t, _tr, info = env.step(action)
                    slots.append(info["uncertainty"])
            except ValueError:               # the carried swap broke a later slot: skip it
                continue
            candidate = Plan(swapped, slots)
            if candidate.total < best.total - 1e-9:
                best, actions = candidate, swapped
                snaps, observations = self._trace(env, actions, seed)
        return best

    @staticmethod
    def _trace(env: MapManagementEnv, actions: list[MapAction], seed: int
               ) -> tuple[list[tuple[Any, ...]], list[SlotObservation]]:
        env.reset(seed)
        snaps, observations = [], []
        for action in actions:
            snaps.append(env.snapshot())
            observations.append(env.observation())
            env.step(action)
        return snaps, observations

    @staticmethod
    def _swap(obs: SlotObservation, actions: list[MapAction], k: int,
              rng: np.random.Generator) -> list[MapAction] | None:
        """``actions`` with one upload or one eviction of slot k swapped, carried forward."""
        act = actions[k]
        if rng.random() < 0.5 and act.upload:
            others = [f for f in obs.candidates if f not in act.upload]
            if not others:
                return None
            old = act.upload[int(rng.integers(len(act.upload)))]
            new = others[int(rng.integers(len(others)))]
            changed = MapAction(sorted(new if f == old else f for f in act.upload),
                                sorted(new if f == old else f for f in act.evict),
                                list(act.restore))
        elif act.evict:
            pool = sorted(obs.map_frames + list(act.upload))
            kept = [f for f in pool if f not in act.evict]
            if not kept:
                return None
            old = act.evict[int(rng.integers(len(act.evict)))]   # now kept ...
            new = kept[int(rng.integers(len(kept)))]             # ... and this one evicted
            changed = MapAction(list(act.upload), sorted(new if f == old else f
                                                         for f in act.evict),
                                list(act.restore))
            old, new = new, old         # later slots that evicted ``new`` evict ``old`` instead
        else:
            return None
        return [*actions[:k], changed, *(_renamed(a, old, new) for a in actions[k + 1:])]
