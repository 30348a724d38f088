"""A whole episode's decisions and what the environment scored them (policies, references).

A plan is what every scorer of map management compares: the actions U_k, C_k of each slot and
the υ_k the environment returned, pooled by frames so that mean υ, the lost share and υ over the
tracked frames of a plan obey mean = (1 - lost) · tracked (docs/architecture.md §2).
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np

from twinslam.policies.actions import MapAction, SlotObservation
from twinslam.policies.protocol import MapPolicy, WorldPlanner
from twinslam.policies.world_model import MapManagementEnv
from twinslam.uncertainty.map_uncertainty import SlotUncertainty, UncertaintyTally


@dataclass
class Plan:
    actions: list[MapAction]
    slots: list[SlotUncertainty]  #: υ_k of every slot, as the environment reported it

    @property
    def objectives(self) -> list[float]:
        """υ_k of every slot (a lost frame scoring 0): the quantity the references minimise."""
        return [s.objective for s in self.slots]

    @property
    def total(self) -> float:
        return float(np.sum(self.objectives))

    @property
    def restored(self) -> int:
        """Archived keyframes the plan brings back, over the episode."""
        return sum(len(a.restore) for a in self.actions)

    @property
    def tally(self) -> UncertaintyTally:
        """Every slot's frames pooled: mean υ, lost share and tracked υ of the episode."""
        return UncertaintyTally.of(self.slots)


def rollout(env: MapManagementEnv, policy: MapPolicy, seed: int) -> Plan:
    """Run ``policy`` for a whole episode from ``reset(seed)``."""
    obs, _ = env.reset(seed)
    policy.reset(seed)
    if isinstance(policy, WorldPlanner):       # a planner imagines the future in env's world
        policy.attach(env)
    actions, slots = [], []
    while True:
        action = policy.decide(obs)
        obs, _reward, _term, trunc, info = env.step(action)
        actions.append(action)
        slots.append(info["uncertainty"])
        if trunc:
            return Plan(actions, slots)


def replay(env: MapManagementEnv, actions: list[MapAction], seed: int) -> Plan:
    """The plan ``actions`` make from ``reset(seed)`` (refused if one breaks a constraint)."""
    env.reset(seed)
    slots = []
    for action in actions:
        _obs, _r, _t, _trunc, info = env.step(action)
        slots.append(info["uncertainty"])
    return Plan(list(actions), slots)


def action_count(obs: SlotObservation) -> int:
    """How many actions :func:`all_actions` would list, without listing them."""
    return (math.comb(len(obs.candidates), obs.n_upload)
            * math.comb(len(obs.map_frames) + obs.n_upload, obs.n_evict))


def all_actions(obs: SlotObservation) -> list[MapAction]:
    """Every (U_k, C_k) of Theorem 1's sizes for one slot: C(|F|, |U|) · C(|V|+|U|, |C|)."""
    out = []
    for up in itertools.combinations(obs.candidates, obs.n_upload):
        pool = sorted(obs.map_frames + list(up))
        for ev in itertools.combinations(pool, obs.n_evict):
            out.append(MapAction(list(up), list(ev)))
    return out
