"""The clairvoyant oracle: knows every future frame and rate, and plans the whole episode.

It bounds what any causal policy can reach, so each policy's gap to it is reported. Two modes:

* **exhaustive** (tiny cases): every (U_k, C_k) of every slot, the true optimum of P1.
* **beam search** (real sizes): at each slot every beam state is expanded with the actions of
  the benchmark policies and random perturbations of them, states are ranked by the objective
  accumulated so far, the best ``beam`` survive. The result is then compared with the complete
  roll-outs of the benchmark policies and the best plan is kept, so the oracle is never worse
  than a policy it knows.

The objective is the penalised υ of :mod:`twinslam.uncertainty.map_uncertainty`, summed over slots.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np

from twinslam.map_management.actions import MapAction, SlotObservation
from twinslam.map_management.policies import Adapt, LatestFrameFirst, MapPolicy, PeriodicalUploading
from twinslam.simulator.env import MapManagementEnv
from twinslam.uncertainty.map_uncertainty import SlotUncertainty


@dataclass
class Plan:
    actions: list[MapAction]
    slots: list[SlotUncertainty]  #: υ_k of every slot, as the environment reported it

    @property
    def objectives(self) -> list[float]:
        """Penalised υ_k of every slot (the quantity the oracle minimises)."""
        return [s.objective for s in self.slots]

    @property
    def total(self) -> float:
        return float(np.sum(self.objectives))


def rollout(env: MapManagementEnv, policy: MapPolicy, seed: int) -> Plan:
    """Run ``policy`` for a whole episode from ``reset(seed)``."""
    obs, _ = env.reset(seed)
    policy.reset(seed)
    actions, slots = [], []
    while True:
        action = policy.decide(obs)
        obs, _reward, _term, trunc, info = env.step(action)
        actions.append(action)
        slots.append(info["uncertainty"])
        if trunc:
            return Plan(actions, slots)


def _all_actions(obs: SlotObservation) -> list[MapAction]:
    out = []
    for up in itertools.combinations(obs.candidates, obs.n_upload):
        pool = sorted(obs.map_frames + list(up))
        for ev in itertools.combinations(pool, obs.n_evict):
            out.append(MapAction(list(up), list(ev)))
    return out


def _perturb(obs: SlotObservation, base: MapAction, rng: np.random.Generator) -> MapAction:
    """Swap one upload and one eviction of ``base`` at random (keeps Theorem 1 sizes)."""
    up = list(base.upload)
    others = [f for f in obs.candidates if f not in up]
    if up and others:
        up[rng.integers(len(up))] = others[rng.integers(len(others))]
    pool = sorted(obs.map_frames + up)
    ev = sorted(rng.choice(pool, obs.n_evict, replace=False).tolist()) if obs.n_evict else []
    if obs.n_evict and rng.random() < 0.5:
        ev = pool[:obs.n_evict]      # keep the "evict oldest" structure half of the time
    return MapAction(sorted(up), ev)


class ClairvoyantOracle:
    name = "oracle"

    def __init__(self, beam: int = 4, perturbations: int = 3,
                 exhaustive_limit: int = 20000) -> None:
        self.beam = beam
        self.perturbations = perturbations
        self.exhaustive_limit = exhaustive_limit
        self.baselines: list[MapPolicy] = [LatestFrameFirst(), PeriodicalUploading(), Adapt()]

    def plan(self, env: MapManagementEnv, seed: int) -> Plan:
        baseline_plans = [rollout(env, p, seed) for p in self.baselines]
        searched = self._search(env, seed)
        return min([searched, *baseline_plans], key=lambda p: p.total)

    def _search(self, env: MapManagementEnv, seed: int) -> Plan:
        rng = np.random.default_rng(seed)
        obs, _ = env.reset(seed)
        beams: list[tuple[float, list[MapAction], list[SlotUncertainty], tuple,
                          SlotObservation]] = [(0.0, [], [], env.snapshot(), obs)]
        exhaustive = self._tiny(env, obs)
        width = self.exhaustive_limit if exhaustive else self.beam
        for _slot in range(env.config.slots):
            children = []
            for total, acts, slots, snap, state_obs in beams:
                for action in self._proposals(state_obs, rng, exhaustive):
                    env.restore(snap)
                    nxt, reward, _t, _tr, info = env.step(action)
                    children.append((total - reward, [*acts, action],
                                     [*slots, info["uncertainty"]], env.snapshot(), nxt))
            children.sort(key=lambda c: c[0])
            beams = children[:width]
        best = beams[0]
        return Plan(best[1], best[2])

    def _tiny(self, env: MapManagementEnv, obs: SlotObservation) -> bool:
        per_slot = len(_all_actions(obs)) if len(obs.candidates) <= 8 else self.exhaustive_limit
        return per_slot ** env.config.slots <= self.exhaustive_limit

    def _proposals(self, obs: SlotObservation, rng: np.random.Generator,
                   exhaustive: bool) -> list[MapAction]:
        if exhaustive:
            return _all_actions(obs)
        base = [p.decide(obs) for p in self.baselines]
        extra = [_perturb(obs, base[i % len(base)], rng) for i in range(self.perturbations)]
        unique: dict[tuple, MapAction] = {}
        for a in base + extra:
            unique[(tuple(sorted(a.upload)), tuple(sorted(a.evict)))] = a
        return list(unique.values())
