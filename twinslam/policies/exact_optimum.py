"""The exact optimum of problem P1 on small instances, by dynamic programming over maps.

Slot k's reward depends only on the maps V^e_k and V^e_{k+1} and the frames F_{k+1}, and the
rates are fixed by the seed, so the best total from slot k on depends only on (k, V^e_k, the
frames of F_k the device tracked — the upload candidates). Forward DP keeps, for every such
state reachable after each slot, the cheapest way to reach it; the cheapest state after the
last slot ends the optimal plan. Every action of Theorem 1's sizes is tried at every reachable
state, so nothing is pruned: the result is the true minimum of Σ υ_k.

Its cost is the number of distinct maps a slot can leave (up to C(frames seen, V_max)) times
the actions per map: a few thousand maps for ≤ 6 frames a slot, V_max ≤ 4 and ≤ 4 slots.
Beyond ``max_maps`` it refuses rather than run for hours.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from twinslam.policies.actions import MapAction
from twinslam.policies.plan import Plan, action_count, all_actions
from twinslam.policies.world_model import MapManagementEnv, state_key
from twinslam.uncertainty.map_uncertainty import SlotUncertainty


class InstanceTooLarge(ValueError):
    """The instance has more reachable maps than the exact optimum is allowed to visit."""


@dataclass
class _Best:
    total: float
    actions: list[MapAction]
    slots: list[SlotUncertainty]
    snapshot: tuple[Any, ...]


def exact_optimum(env: MapManagementEnv, seed: int, max_maps: int = 50_000) -> Plan:
    """The plan of minimum Σ_k υ_k from ``reset(seed)``: the optimum no policy can beat.
    Refused (ValueError) on a world whose policies may restore archived keyframes: the search
    tries Theorem 1's uploads and evictions only, so there it would not be the optimum."""
    if env.config.restore_keyframes > 0:
        raise ValueError("the exact optimum searches uploads and evictions, not restores: on a "
                         "world with restore_keyframes > 0 it would not be the optimum")
    env.reset(seed)
    return best_continuation(env, env.config.slots, max_maps)


def best_continuation(env: MapManagementEnv, slots: int, max_maps: int = 50_000,
                      max_actions: int | None = None) -> Plan:
    """The plan of minimum Σ υ over the next ``slots`` slots from the environment's current
    state (the forward DP of the module docstring; the environment is left wherever the
    search last stepped it). :class:`InstanceTooLarge` when a slot can leave more than
    ``max_maps`` maps, or a state offers more than ``max_actions`` actions (counted before
    any is built: at full size there are ~10¹¹)."""
    layer: dict[tuple[Any, ...], _Best] = {(): _Best(0.0, [], [], env.snapshot())}
    for slot in range(slots):
        nxt: dict[tuple[Any, ...], _Best] = {}
        for best in layer.values():
            env.restore(best.snapshot)
            obs = env.observation()
            if max_actions is not None and action_count(obs) > max_actions:
                raise InstanceTooLarge(f"slot {obs.slot} offers more than {max_actions} "
                                       "actions")
            for action in all_actions(obs):
                env.restore(best.snapshot)
                _obs, reward, _t, _trunc, info = env.step(action)
                after = env.snapshot()
                key = state_key(after)
                known = nxt.get(key)
                if known is not None and known.total <= best.total - reward:
                    continue                 # the same state reached at no lower cost
                nxt[key] = _Best(best.total - reward, [*best.actions, action],
                                 [*best.slots, info["uncertainty"]], after)
            if len(nxt) > max_maps:
                raise InstanceTooLarge(
                    f"slot {slot} can leave more than {max_maps} distinct maps: too large for "
                    "the exact optimum (use fewer frames a slot, a smaller V_max or fewer slots)")
        layer = nxt
    best = min(layer.values(), key=lambda b: b.total)
    return Plan(best.actions, best.slots)
