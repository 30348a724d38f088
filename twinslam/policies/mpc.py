"""``mpc``: a causal planner that looks H slots ahead.

Each slot it scores candidate actions (U_k, C_k) by the objective they lead to over the next
H slots in an *imagined* future, and takes the best:

    a_k = argmin_a  1/S Σ_s [ υ_k(a) + min over the H - 1 later slots' plans of Σ υ ]

in S scenarios. What it may know is only what a device and an edge know at slot k:

* **rates** — ``regime``: S state paths drawn from the Bayesian regime twin fed with the
  states observed so far (the next state from its posterior predictive, later ones from its
  mean regime matrix), each state at the mean rate observed in it (the current rate before it
  was seen); ``markov``: the same from transition counts (the paper's Markov model, KT
  smoothed); ``variational``: the same from the variational twin (paper §V), learning within
  the episode — retrained every ``W`` slots on the states seen (the policy registry builds
  it: it loads torch, which the simulator never does); ``last``: no model, the current state
  and rate persist; ``oracle``: the true future rates (the known-future control only);
* **frames** — ``motion``: the camera keeps moving through the sequence as it did across this
  slot (constant velocity in frames, turned back at the sequence's ends) — in the simulator the
  covisibility of the frames at the extrapolated poses, live it would be the frusta's overlap
  there; ``persistence``: the next slots see what this slot saw; ``oracle``: the true frames.

With an archive (the environment's ``archive_keyframes``) each candidate first action is
also tried with the archived keyframes the predicted next-slot frames need brought back
(:func:`~twinslam.policies.restoring.with_restores`): ``mpc`` plans restores with the
same imagined future it plans uploads with.

The later slots' plans: every action exactly (dynamic programming over maps, as
:mod:`~twinslam.policies.exact_optimum`) while the instance is small enough, else the best of
the base policies' (LFF, ADAPT) roll-outs. Candidate first actions: all of them when there are
at most ``max_actions``, else the base policies' actions and random swaps of them. With a known
future and H covering the rest of the episode it is the exact optimum (tests).

It plans in the world model (:mod:`twinslam.policies.world_model`) here; at the edge
(:mod:`edge_mapper.planning_world`) the same planner plans in a world built each slot from the
live map, the device's poses and the frames predicted at its extrapolated poses.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from twinslam.policies.actions import MapAction, SlotObservation
from twinslam.policies.exact_optimum import InstanceTooLarge, best_continuation
from twinslam.policies.plan import action_count, all_actions
from twinslam.policies.protocol import MapPolicy
from twinslam.policies.reference import swap_one
from twinslam.policies.restoring import with_restores
from twinslam.policies.rules import Adapt, LatestFrameFirst
from twinslam.policies.world_model import MapManagementEnv, PredictedStream
from twinslam.twin.markov import MarkovCounts
from twinslam.twin.regime_twin import RegimeConfig, RegimeTwin

RATE_MODELS = ("regime", "markov", "variational", "last", "oracle")
#: builds a learned rate model the simulator cannot (torch): (N states, seed, W) → a model
#: with observe/retrain/predict/transition_matrix (:mod:`twinslam.twin.rate_model`)
LearnedRates = Callable[[int, int, int], Any]
FRAME_PREDICTORS = ("motion", "persistence", "oracle")


@dataclass(frozen=True)
class MpcConfig:
    horizon: int = 3             #: H, slots planned (this one included)
    scenarios: int = 4           #: S, rate scenarios the plan is averaged over
    rates: str = "regime"
    frames: str = "motion"
    max_actions: int = 64        #: first actions tried exhaustively up to this many
    max_states: int = 2_000      #: maps a slot, actions a state, of an exact later plan
    swaps: int = 6               #: random swaps of the base actions when not exhaustive
    retrain: int = 20            #: W, slots between retrains of a learned rate model

    def label(self) -> str:
        """``mpc``, or ``mpc:`` and the options that differ from the defaults."""
        keys = {"horizon": "H", "scenarios": "S", "rates": "rates", "frames": "frames",
                "max_actions": "actions", "max_states": "states", "swaps": "swaps",
                "retrain": "W"}
        default = MpcConfig()
        changed = [f"{short}={getattr(self, name)}" for name, short in keys.items()
                   if getattr(self, name) != getattr(default, name)]
        return "mpc" + (":" + "/".join(changed) if changed else "")

    def check(self) -> None:
        if self.horizon < 1 or self.scenarios < 1 or self.max_actions < 1 or self.swaps < 0 \
                or self.retrain < 1 or self.max_states < 1:
            raise ValueError("mpc: H, S, W, actions and states must be >= 1, swaps >= 0")
        if self.rates not in RATE_MODELS:
            raise ValueError(f"mpc: rates {self.rates!r}, one of {', '.join(RATE_MODELS)}")
        if self.frames not in FRAME_PREDICTORS:
            raise ValueError(f"mpc: frames {self.frames!r}, one of "
                             f"{', '.join(FRAME_PREDICTORS)}")


def parse_mpc(spec: str) -> MpcConfig:
    """``mpc`` or ``mpc:H=4/S=8/rates=regime/frames=motion`` (any subset, ``/`` or ``,``
    between them: ``/`` where a comma separates policies, as in ``--policy lff,mpc:H=4/S=8``)."""
    _, _, options = spec.partition(":")
    config = MpcConfig()
    keys = {"H": "horizon", "S": "scenarios", "rates": "rates", "frames": "frames",
            "actions": "max_actions", "states": "max_states", "swaps": "swaps", "W": "retrain"}
    for part in filter(None, (p.strip() for p in options.replace("/", ",").split(","))):
        key, eq, value = part.partition("=")
        if not eq or key not in keys:
            raise ValueError(f"mpc option {part!r}: use {', '.join(f'{k}=' for k in keys)}")
        field_name = keys[key]
        try:
            typed: Any = value if field_name in ("rates", "frames") else int(value)
        except ValueError:
            raise ValueError(f"mpc option {part!r}: {key} takes an integer") from None
        config = replace(config, **{field_name: typed})
    config.check()
    return config


class MpcPlanner:
    """The ``mpc`` policy (module docstring). ``attach(env)`` hands it the simulator's
    environment whose world it imagines; :func:`~twinslam.policies.plan.rollout` does."""

    name = "mpc"

    def __init__(self, config: MpcConfig | None = None,
                 base: Sequence[MapPolicy] | None = None,
                 learned_rates: LearnedRates | None = None) -> None:
        self.config = config or MpcConfig()
        self.config.check()
        if self.config.rates == "variational" and learned_rates is None:
            raise ValueError("mpc: rates=variational needs the variational twin, which the "
                             "policy registry builds (make_policy('mpc:rates=variational'))")
        self._learned = learned_rates
        self.name = self.config.label()
        self.base: list[MapPolicy] = (list(base) if base is not None
                                      else [LatestFrameFirst(), Adapt()])
        self._env: MapManagementEnv | None = None
        self.reset(0)

    def with_config(self, config: MpcConfig) -> MpcPlanner:
        """A fresh planner with other options, the same base policies and rate model maker."""
        return MpcPlanner(config, self.base, self._learned)

    def attach(self, env: MapManagementEnv) -> None:
        self._env = env

    def reset(self, seed: int | None = None) -> None:
        self._rng = np.random.default_rng(seed)
        self._seed = seed or 0
        self._twin: Any = None     # RegimeTwin, MarkovCounts or a learned model
        self._rates: dict[int, list[float]] = {}
        self._observed = -1

    # -- what it knows ------------------------------------------------------------------------

    def _observe(self, obs: SlotObservation) -> None:
        if obs.slot == self._observed:
            return
        if self._twin is None or self._twin.n_states != obs.n_states:
            rates = self.config.rates
            self._twin = (MarkovCounts(obs.n_states, pseudo_count=0.5) if rates == "markov"
                          else self._learned(obs.n_states, self._seed, self.config.retrain)
                          if rates == "variational" and self._learned is not None
                          else RegimeTwin(RegimeConfig(n_states=obs.n_states)))
        if self._twin.observe(obs.rate_state):      # a learned model's retrain is due
            self._twin.retrain()
        self._rates.setdefault(obs.rate_state, []).append(obs.rate_mbps)
        self._observed = obs.slot

    def _scenarios(self, obs: SlotObservation) -> list[list[tuple[int, float]] | None]:
        """Rates of slots k+1 … k+H-1 per scenario (None: the true ones)."""
        cfg = self.config
        if cfg.rates == "oracle" or cfg.horizon == 1:
            return [None]
        if cfg.rates == "last":
            return [[(obs.rate_state, obs.rate_mbps)] * (cfg.horizon - 1)]
        assert self._twin is not None
        matrix = self._twin.transition_matrix()
        # a filter reads the newest state only; a learned model its window of them
        if self.config.rates == "variational":
            following = self._twin.predict(obs.rate_history)
            following = following / following.sum()        # a float32 softmax's rounding
        else:
            following = self._twin.predict([obs.rate_state])
        out: list[list[tuple[int, float]] | None] = []
        for _ in range(cfg.scenarios):
            state = int(self._rng.choice(obs.n_states, p=following))
            path = []
            for _h in range(cfg.horizon - 1):
                seen = self._rates.get(state)
                path.append((state, float(np.mean(seen)) if seen else obs.rate_mbps))
                row = matrix[state]
                state = int(self._rng.choice(obs.n_states, p=row / row.sum()))
            out.append(path)
        return out

    def _world(self, env: MapManagementEnv, obs: SlotObservation,
               rates: list[tuple[int, float]] | None) -> MapManagementEnv:
        stream = None
        if self.config.frames != "oracle":
            f = env.config.slot_frames
            seen = (obs.slot + 1) * f
            stream = PredictedStream(env.stream, seen, f, env.dataset.n_frames,
                                     self.config.frames)
        return env.imagine(rates, stream)

    # -- deciding -----------------------------------------------------------------------------

    def decide(self, obs: SlotObservation) -> MapAction:
        env = self._env
        if env is None:
            raise RuntimeError("mpc plans in a world model: attach(env) first (twinslam sim "
                               "and experiment do; at the edge edge_mapper.planning_world's "
                               "LiveMpc builds one from the live map each slot)")
        self._observe(obs)
        worlds = [self._world(env, obs, rates) for rates in self._scenarios(obs)]
        first = self._first_actions(obs)
        if obs.n_restore > 0:           # with an archive: each also with the restores that
            first += self._restoring(obs, first, worlds[0])   # the predicted frames need
        if len(first) == 1:
            return first[0]
        costs = np.zeros(len(first))
        for world in worlds:
            start = world.snapshot()
            for i, action in enumerate(first):
                world.restore(start)
                _o, reward, _t, trunc, _info = world.step(action)
                costs[i] += -reward + (0.0 if trunc else
                                       self._cost_to_go(world, self.config.horizon - 1))
        return first[int(np.argmin(costs))]

    def _first_actions(self, obs: SlotObservation) -> list[MapAction]:
        if action_count(obs) <= self.config.max_actions:
            return all_actions(obs)
        proposals = [p.decide(obs) for p in self.base]
        for _ in range(self.config.swaps):
            proposals.append(swap_one(obs, proposals[int(self._rng.integers(len(self.base)))],
                                   self._rng))
        unique: dict[tuple[tuple[int, ...], tuple[int, ...]], MapAction] = {}
        for a in proposals:
            unique.setdefault((tuple(sorted(a.upload)), tuple(sorted(a.evict))), a)
        return list(unique.values())

    @staticmethod
    def _restoring(obs: SlotObservation, first: list[MapAction], world: MapManagementEnv
                   ) -> list[MapAction]:
        """``first``'s actions with archived keyframes brought back for the next slot's
        frames as ``world`` predicts them (:func:`with_restores`), those that restore any."""
        predicted = replace(obs, weights=world.weights)
        coming = world.slot_frames(obs.slot + 1)
        out = []
        for action in first:
            restoring = with_restores(predicted, action, coming)
            if restoring.restore:
                out.append(restoring)
        return out

    def _cost_to_go(self, world: MapManagementEnv, slots: int) -> float:
        """The least Σ υ of the next ``slots`` slots (at most to the episode's end) from the
        world's state: exact while the maps they can leave stay under ``max_states``, else
        the best base roll-out."""
        slots = min(slots, world.config.slots - world.observation().slot)
        if slots <= 0:
            return 0.0
        start = world.snapshot()
        try:
            return best_continuation(world, slots, self.config.max_states,
                                     self.config.max_states).total
        except InstanceTooLarge:
            pass
        best = np.inf
        for policy in self.base:
            world.restore(start)
            total = 0.0
            for _ in range(slots):
                _o, reward, _t, _trunc, _i = world.step(policy.decide(world.observation()))
                total -= reward
            best = min(best, total)
        world.restore(start)
        return float(best)
