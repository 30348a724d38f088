"""Training the AMM policy: Algorithm 2 of the paper on the offline simulator.

Each slot: the rate model gives the state's latent features (line 4); the actor scores the
frames and exploration noise is added to the scores (line 5); the environment plays the slot
(line 6) and the tuple goes to the real buffer; the rate model samples J next rates and, for
each, an exploratory action is played in an emulated copy of the slot — the artificial tuples
(Algorithm 1, line 4); then the critic takes a TD step (eq. 25) and the actor a deterministic
policy-gradient step (eq. 26) on one blended batch of I real and |Ξ| − I artificial tuples
(lines 7–9), and the target networks follow softly. The rate model observes each slot's rate
and retrains every W slots (lines 11–13).

Episodes use training seeds only (``TRAINING_SEED_BASE`` + …), so the channel realisations and
start frames of an evaluation (seeds 0, 1, …) are never seen in training.
"""

from __future__ import annotations

import copy
import csv
import math
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch

from twinslam.covisibility.dataset import CovisibilityDataset
from twinslam.policies.actions import SlotObservation
from twinslam.policies.learned.networks import Actor, Critic, hard_flags, soft_flags
from twinslam.policies.learned.policy import CHECKPOINT_FORMAT, MbrlPolicy
from twinslam.policies.learned.replay import (
    ReplayBuffer,
    Transition,
    blended_batch,
    collate,
    collate_flags,
)
from twinslam.policies.learned.state import (
    GraphState,
    action_from_scores,
    build_state,
    context_size,
)
from twinslam.policies.plan import rollout
from twinslam.policies.world_model import MapManagementEnv, SimConfig
from twinslam.slot_protocol import table1
from twinslam.twin.rate_model import RateModel
from twinslam.twin.registry import (
    DEFAULT_RATE_MODEL,
    POLICY_RATE_MODELS,
    RateModelSettings,
    canonical,
    check_names,
    make_rate_model,
)
from twinslam.uplink.channels import parse_channel

TRAINING_SEED_BASE = 100_000
VALIDATION_SEED_BASE = 50_000    #: the actor kept is the best on these (never evaluated on)
SNAPSHOTS_FORMAT = "twinslam-amm-snapshots/1"


@dataclass(frozen=True)
class TrainConfig:
    channel: str = "markov:N=2"
    rate_range: tuple[float, float] = table1.RATE_RANGE_MBPS
    vmax: int = table1.VMAX
    slot_frames: int = table1.SLOT_FRAMES
    slots: int = 3000                 #: real slots in all
    episode_slots: int = 200
    seed: int = 0
    rate_model: str = DEFAULT_RATE_MODEL   #: regime | variational | lstm | markov
    #: paper (the paper's AMM: GCN scores, no ADAPT prior or features) | residual (ADAPT + RL)
    actor: str = "residual"
    retrain_every: int = 100          #: W
    history: int = 8                  #: rate states in the context
    batch_size: int = 64              #: |Ξ|
    real_fraction: float = 0.5        #: I / |Ξ| when J > 0; 1 = no artificial experiences
    #: J, artificial tuples per real slot. 0 (real experiences only) by default: the blended
    #: replay helped at none of 300 / 1000 / 3000 real slots (docs/results/twin.md);
    #: the paper's Algorithm 2 is J = 2, I / |Ξ| = 1/2
    artificial_per_real: int = 0
    gamma: float = 0.9
    actor_lr: float = 1e-4
    critic_lr: float = 1e-3
    tau: float = 0.01                 #: soft target update
    #: exploration noise on the scores (std); ADAPT's prior separates its classes by ≥ 1
    noise: float = 1.0
    artificial_noise: float = 1.0     #: noise of the artificial tuples' exploratory actions
    #: of the relaxed action in the actor's gradient; ADAPT's prior separates its classes
    #: of frames by ≥ 1, so a much smaller T leaves the actor without a gradient
    temperature: float = 1.0
    warmup_slots: int = 100           #: slots played before the first update
    replay_capacity: int = 5000
    log_every: int = 50               #: slots between progress lines / log rows
    #: the actor's loss adds this × the mean square of its correction to ADAPT's scores
    #: (TD3+BC's idea: leave the prior only where the critic's gain outweighs it)
    correction_weight: float = 0.05
    validate_every: int = 500         #: slots between validations (0: never; keep the last)
    validation_seeds: int = 4
    validation_slots: int = 100

    @property
    def real_count(self) -> int:
        return self.batch_size if self.artificial_per_real == 0 else \
            round(self.real_fraction * self.batch_size)

    def sim_config(self) -> SimConfig:
        return SimConfig(vmax=self.vmax, slot_frames=self.slot_frames, slots=self.episode_slots,
                         history=self.history)


@dataclass
class TrainLog:
    rows: list[dict[str, float]] = field(default_factory=list)

    def write_csv(self, path: Path) -> None:
        if not self.rows:
            return
        with Path(path).open("w", newline="") as fh:
            writer = csv.DictWriter(fh, fieldnames=list(self.rows[0]))
            writer.writeheader()
            writer.writerows(self.rows)


class AmmTrainer:
    def __init__(self, config: TrainConfig, dataset: CovisibilityDataset,
                 progress: Callable[[str], None] | None = None,
                 snapshots: bool = False,
                 on_validation: Callable[[AmmTrainer], None] | None = None) -> None:
        """``snapshots``: also keep the checkpoint of every validated actor, not only the
        best (:meth:`save_snapshots`; what a learning curve evaluates on held-out data).
        ``on_validation``: called after every validation (e.g. to save what there is so far:
        a long training that is stopped keeps its kept actor and its curve)."""
        self.config = config
        self.on_validation = on_validation
        self.keep_snapshots = snapshots
        #: (slot, checkpoint blob) of every validation, with ``snapshots``
        self.snapshots: list[tuple[int, dict[str, Any]]] = []
        self.dataset = dataset
        self.progress = progress
        torch.manual_seed(config.seed)
        self.rng = np.random.default_rng(config.seed)
        self.env = MapManagementEnv(dataset, parse_channel(config.channel, config.rate_range,
                                                           config.seed), config.sim_config())
        n_states = self.env.channel.n_states
        check_names([config.rate_model], POLICY_RATE_MODELS)
        self.rate_model: RateModel = make_rate_model(
            canonical(config.rate_model), RateModelSettings(
                n_states=n_states, retrain_every=config.retrain_every, seed=config.seed))
        c = context_size(config.history, n_states, self.rate_model.feature_size)
        self.actor, self.critic = Actor(c, config.actor), Critic(c)
        self.actor_target = copy.deepcopy(self.actor)
        self.critic_target = copy.deepcopy(self.critic)
        self.actor_opt = torch.optim.Adam(self.actor.parameters(), lr=config.actor_lr)
        self.critic_opt = torch.optim.Adam(self.critic.parameters(), lr=config.critic_lr)
        self.real = ReplayBuffer(config.replay_capacity)
        self.artificial = ReplayBuffer(config.replay_capacity * max(config.artificial_per_real, 1))
        #: rewards are −υ (~10³); they are standardised by the warm-up slots' statistics
        self.reward_mean, self.reward_std = 0.0, 1.0
        self.log = TrainLog()
        #: (slot, validation υ) of every validation; the best actor's checkpoint
        self.validations: list[tuple[int, float]] = []
        self.best_validation = math.inf
        self.best_blob: dict[str, Any] | None = None

    # -- acting ---------------------------------------------------------------------------

    def state_of(self, obs: SlotObservation, rate_model: RateModel | None = None
                 ) -> GraphState:
        model = rate_model or self.rate_model
        features = model.features(obs.rate_history)
        if not np.all(np.isfinite(features)):
            raise FloatingPointError(f"slot {obs.slot}: the {model.name} rate model's "
                                     f"features are not finite: {features}")
        return build_state(obs, features, self.config.history,
                           adapt_features=self.config.actor == "residual")

    @torch.no_grad()
    def scores(self, state: GraphState) -> np.ndarray:
        b = collate([state])
        return np.asarray(self.actor(b.x, b.prop, b.mask, b.context)[0].numpy())

    def _norm(self, reward: float) -> float:
        return (reward - self.reward_mean) / self.reward_std

    # -- training -------------------------------------------------------------------------

    def train(self) -> TrainLog:
        cfg = self.config
        played, episode, start = 0, 0, time.perf_counter()
        warm_rewards: list[float] = []
        if cfg.validate_every:
            self._keep_if_best(0)    # the untrained actor (residual: ADAPT's decisions)
        pending: list[tuple[GraphState, np.ndarray, float, GraphState, bool]] = []
        while played < cfg.slots:
            obs, _ = self.env.reset(TRAINING_SEED_BASE + 1000 * cfg.seed + episode)
            self.rate_model.reset()          # a filter (regime, counts) starts each episode
            self._observe(obs.rate_state)
            state = self.state_of(obs)
            returns: list[float] = []
            while played < cfg.slots:
                before, history = self.env.snapshot(), obs.rate_history
                scores = self.scores(state)          # the real and the artificial actions'
                noisy = scores + self.rng.normal(0.0, cfg.noise, state.size)
                action, flags = action_from_scores(state, noisy)
                obs, reward, _term, trunc, _info = self.env.step(action)
                # a filter's posterior before the real next state: the artificial next states
                # are drawn from it and observed by copies of it, never knowing the real one
                prior = (copy.deepcopy(self.rate_model)
                         if self.rate_model.online and cfg.artificial_per_real else None)
                self._observe(obs.rate_state)
                next_state = self.state_of(obs)
                returns.append(-reward)
                items = [(state, flags, reward, next_state, True)]
                items += self._artificial(state, scores, before, history, prior)
                played += 1
                if played <= cfg.warmup_slots:
                    warm_rewards.append(reward)
                    pending += items
                    if played == cfg.warmup_slots:
                        self.reward_mean = float(np.mean(warm_rewards))
                        self.reward_std = float(np.std(warm_rewards)) or 1.0
                        for item in pending:
                            self._store(*item)
                        pending = []
                else:
                    for item in items:
                        self._store(*item)
                    losses = self.update()
                    if played % cfg.log_every == 0:
                        self._log(played, episode, returns, losses, start)
                    if cfg.validate_every and played % cfg.validate_every == 0:
                        self._keep_if_best(played)
                state = next_state
                if trunc:
                    break
            episode += 1
        for item in pending:                       # fewer slots than the warm-up
            self._store(*item)
        if cfg.validate_every and played % cfg.validate_every:
            self._keep_if_best(played)
        return self.log

    def _observe(self, state: int) -> None:
        """A real slot's state into the rate model; a learned one retrains when it is due
        (Algorithm 2 lines 11–13)."""
        if self.rate_model.observe(state):
            self.rate_model.retrain()

    def _artificial(self, state: GraphState, scores: np.ndarray, before: tuple[Any, ...],
                    history: list[int], prior: RateModel | None = None
                    ) -> list[tuple[GraphState, np.ndarray, float, GraphState, bool]]:
        """J artificial tuples from the slot just played (paper eq. 23); ``scores`` are the
        actor's for ``state``, explored around with the artificial noise. ``prior``: an online
        rate model as it was before the real next state, which the d̂_{k+1} are drawn from and
        whose copies observe them (the next state's features are then those after d̂)."""
        cfg = self.config
        out = []
        rates = self.env.channel.rates
        model = prior or self.rate_model
        for d_hat in model.sample_next(history, cfg.artificial_per_real, self.rng):
            noisy = scores + self.rng.normal(0.0, cfg.artificial_noise, state.size)
            action, flags = action_from_scores(state, noisy)
            obs, reward, _info = self.env.emulate(before, action,
                                                  (int(d_hat), float(rates[int(d_hat)])))
            after = None
            if prior is not None:
                after = copy.deepcopy(prior)
                after.observe(int(d_hat))
            out.append((state, flags, reward, self.state_of(obs, after), False))
        return out

    def _store(self, state: GraphState, flags: np.ndarray, reward: float,
               next_state: GraphState, real: bool) -> None:
        if not math.isfinite(reward):
            raise FloatingPointError(f"a {'real' if real else 'artificial'} reward is not "
                                     f"finite ({reward})")
        item = Transition(state, flags, self._norm(reward), next_state)
        (self.real if real else self.artificial).add(item)

    def update(self) -> dict[str, float]:
        """One critic TD step (eq. 25) and one actor policy-gradient step (eq. 26) on a
        blended batch, then the soft target update."""
        cfg = self.config
        batch = blended_batch(self.real, self.artificial, cfg.batch_size, cfg.real_count,
                              self.rng)
        n = max(max(t.state.size for t in batch), max(t.next_state.size for t in batch))
        s = collate([t.state for t in batch], n)
        s2 = collate([t.next_state for t in batch], n)
        flags = collate_flags(batch, n)
        reward = torch.tensor([t.reward for t in batch], dtype=torch.float32)
        with torch.no_grad():
            a2 = self.actor_target(s2.x, s2.prop, s2.mask, s2.context)
            f2 = hard_flags(a2, s2.x, s2.mask, s2.n_upload, s2.n_evict)
            target = reward + cfg.gamma * self.critic_target(s2.x, s2.prop, s2.mask,
                                                             s2.context, f2)
        q = self.critic(s.x, s.prop, s.mask, s.context, flags)
        critic_loss = torch.nn.functional.mse_loss(q, target)
        if not torch.isfinite(critic_loss):
            raise FloatingPointError("the critic's TD loss is not finite: a state feature or "
                                     "a reward is (training stopped before it spread)")
        self.critic_opt.zero_grad()
        critic_loss.backward()
        torch.nn.utils.clip_grad_norm_(self.critic.parameters(), 10.0)
        self.critic_opt.step()

        correction = self.actor.correction(s.x, s.prop, s.mask, s.context)
        scores = self.actor.base_scores(s.x, s.mask) + correction
        relaxed = soft_flags(scores, s.x, s.mask, s.n_upload, s.n_evict, cfg.temperature)
        actor_loss = -self.critic(s.x, s.prop, s.mask, s.context, relaxed).mean()
        if cfg.actor == "residual":          # stay near ADAPT unless the critic says otherwise
            actor_loss = actor_loss + cfg.correction_weight * (correction ** 2).sum() / \
                s.mask.sum()
        self.actor_opt.zero_grad()
        actor_loss.backward()
        torch.nn.utils.clip_grad_norm_(self.actor.parameters(), 10.0)
        self.actor_opt.step()
        with torch.no_grad():
            for net, tgt in ((self.actor, self.actor_target), (self.critic, self.critic_target)):
                for p, pt in zip(net.parameters(), tgt.parameters(), strict=True):
                    pt.mul_(1.0 - cfg.tau).add_(p, alpha=cfg.tau)
        return {"critic_loss": critic_loss.item(), "actor_loss": actor_loss.item(),
                "q": q.mean().item()}

    def _log(self, played: int, episode: int, returns: list[float],
             losses: dict[str, float], start: float) -> None:
        row = {"slot": played, "episode": episode,
               "mean_uncertainty_last_50": float(np.mean(returns[-50:])) if returns
               else math.nan,
               **losses, "prior": self.actor.prior.item(), "seconds": time.perf_counter() - start}
        self.log.rows.append(row)
        if self.progress:
            self.progress(f"slot {played}/{self.config.slots}  episode {episode}  "
                          f"υ(last 50) {row['mean_uncertainty_last_50']:.1f}  "
                          f"critic {losses['critic_loss']:.3f}  Q {losses['q']:.2f}  "
                          f"{row['seconds']:.0f} s")

    # -- persistence ----------------------------------------------------------------------

    def checkpoint_blob(self) -> dict[str, Any]:
        """Actor, rate model and the settings needed to run them."""
        return {"format": CHECKPOINT_FORMAT, "config": asdict(self.config),
                "n_states": self.env.channel.n_states,
                "actor": copy.deepcopy(self.actor.state_dict()),
                "rate_model": self.rate_model.name,
                "rate_model_state": copy.deepcopy(self.rate_model.state_dict()),
                "validation": self.best_validation,
                "validations": [[slot, score] for slot, score in self.validations]}

    def save(self, path: Path) -> None:
        """The checkpoint of the kept actor (the best validated one), atomically."""
        path = Path(path)
        blob = self.best_blob or self.checkpoint_blob()
        tmp = path.with_name(path.name + ".tmp")
        torch.save(blob, tmp)
        tmp.replace(path)

    def save_snapshots(self, path: Path) -> None:
        """Every validated actor's checkpoint (slot, blob), in training order, and the slot
        of the one kept, atomically; :func:`load_snapshots` reads them back."""
        if not self.keep_snapshots:
            raise RuntimeError("this trainer keeps no snapshots (snapshots=False)")
        path = Path(path)
        kept = min(self.validations, key=lambda v: v[1])[0] if self.validations else -1
        tmp = path.with_name(path.name + ".tmp")
        torch.save({"format": SNAPSHOTS_FORMAT, "seed": self.config.seed, "kept_slot": kept,
                    "snapshots": [[slot, blob] for slot, blob in self.snapshots]}, tmp)
        tmp.replace(path)

    def validate(self) -> float:
        """Mean υ of the current actor (no noise) over the validation seeds' episodes."""
        cfg = self.config
        policy = MbrlPolicy.from_blob(self.checkpoint_blob())
        sim = SimConfig(vmax=cfg.vmax, slot_frames=cfg.slot_frames, slots=cfg.validation_slots,
                        history=cfg.history)
        means = []
        for i in range(cfg.validation_seeds):
            seed = VALIDATION_SEED_BASE + 1000 * cfg.seed + i
            env = MapManagementEnv(self.dataset, parse_channel(cfg.channel, cfg.rate_range,
                                                               seed), sim)
            means.append(float(np.mean(rollout(env, policy, seed).objectives)))
        return float(np.mean(means))

    def _keep_if_best(self, played: int) -> None:
        score = self.validate()
        self.validations.append((played, score))
        if self.keep_snapshots:
            self.snapshots.append((played, self.checkpoint_blob()))
        if score < self.best_validation:
            self.best_validation = score
            self.best_blob = self.checkpoint_blob()
        if self.progress:
            self.progress(f"validation at slot {played}: υ {score:.1f} (best "
                          f"{self.best_validation:.1f})")
        if self.on_validation:
            self.on_validation(self)


def load_snapshots(path: Path) -> tuple[int, int, list[tuple[int, dict[str, Any]]]]:
    """(training seed, kept slot, [(slot, checkpoint blob)]) of a :meth:`save_snapshots`
    file; anything else is a ValueError naming the file."""
    try:
        blob = torch.load(Path(path), map_location="cpu", weights_only=False)
    except (OSError, RuntimeError, EOFError) as exc:
        raise ValueError(f"{path}: not a readable snapshots file ({exc})") from exc
    if not isinstance(blob, dict) or blob.get("format") != SNAPSHOTS_FORMAT:
        raise ValueError(f"{path}: not a training's snapshots (`twinslam train --snapshots` "
                         f"writes them; expected format {SNAPSHOTS_FORMAT})")
    return (int(blob["seed"]), int(blob["kept_slot"]),
            [(int(slot), b) for slot, b in blob["snapshots"]])
