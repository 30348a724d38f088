"""The learned map-management policy: state graph, actions, artificial experiences,
blended replay, training and the trained policy behind the common policy interface."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from edge_mapper.edge_core import EdgeMapperCore
from twinslam.covisibility.dataset import CovisibilityDataset, load_covisibility
from twinslam.live.launcher import preloaded_nodes
from twinslam.policies.learned.state import (
    NODE_FEATURES,
    action_from_scores,
    build_state,
    context_size,
    select,
)
from twinslam.policies.plan import rollout
from twinslam.policies.registry import make_policy
from twinslam.policies.rules import Adapt, LatestFrameFirst
from twinslam.policies.world_model import MapManagementEnv, SimConfig
from twinslam.twin.markov import MarkovCounts
from twinslam.uplink.channels import parse_channel

#: torch (and torch_geometric) load inside the tests, and the tests that load them run on one
#: worker: every xdist worker collects every module, and collecting the suite costs 3 s of CPU
#: without torch, 7 s with it
pytestmark = pytest.mark.xdist_group("torch")

COVIS = Path(__file__).resolve().parents[1] / "data" / "7scenes-redkitchen-1000.covis.npz"

#: node processes forked as the launchers fork theirs (twinslam.live.node_fork_server)
FORKS = preloaded_nodes()


@pytest.fixture(scope="module")
def kitchen() -> CovisibilityDataset:
    return load_covisibility(COVIS)


def _env(dataset: CovisibilityDataset, seed: int = 0, slots: int = 30,
         paper_rule: bool = False) -> MapManagementEnv:
    config = SimConfig.paper_rule(slots=slots) if paper_rule else SimConfig(slots=slots)
    return MapManagementEnv(dataset, parse_channel("markov:N=2", seed=seed), config)


def _played(env: MapManagementEnv, slots: int, seed: int = 0, candidates: int = 8):
    """The observation after at least ``slots`` LFF slots, at the first slot with
    ``candidates`` frames the device tracked (a full map and a fresh slot to upload from)."""
    obs, _ = env.reset(seed)
    for k in range(env.config.slots - 2):
        if k >= slots and len(obs.candidates) >= candidates:
            return obs
        obs, *_ = env.step(LatestFrameFirst().decide(obs))
    raise AssertionError(f"no slot with {candidates} tracked frames in the episode")


def test_state_graph_describes_the_map_and_the_candidates(kitchen: CovisibilityDataset) -> None:
    obs = _played(_env(kitchen), 8)
    state = build_state(obs, np.zeros(3, np.float32), history=8)
    nv, nf = len(obs.map_frames), len(obs.candidates)
    assert state.size == nv + nf and state.n_map == nv
    assert state.nodes.shape == (nv + nf, NODE_FEATURES)
    assert state.nodes[:nv, 0].all() and not state.nodes[nv:, 0].any()      # in map
    assert state.nodes[nv:, 1].all() and not state.nodes[:nv, 1].any()      # candidate
    assert state.context.shape == (context_size(8, 2, 3),)
    w = obs.weight_block(list(state.frames), list(state.frames))
    assert np.allclose(state.adjacency.astype(np.float64), np.log1p(w), atol=1e-2)
    greedy = Adapt().decide(obs)
    flagged_up = {state.frames[i] for i in np.flatnonzero(state.nodes[:, 8])}
    flagged_ev = {state.frames[i] for i in np.flatnonzero(state.nodes[:, 9])}
    assert flagged_up == set(greedy.upload) and flagged_ev == set(greedy.evict)


def test_any_scores_give_an_action_the_environment_accepts(kitchen: CovisibilityDataset
                                                           ) -> None:
    env = _env(kitchen, slots=25)
    obs, _ = env.reset(5)
    rng = np.random.default_rng(0)
    for _ in range(25):
        state = build_state(obs, np.zeros(0, np.float32), history=8)
        action, flags = action_from_scores(state, rng.normal(size=state.size))
        assert len(action.upload) == obs.n_upload and len(action.evict) == obs.n_evict
        assert flags[:, 0].sum() == obs.n_upload and flags[:, 1].sum() == obs.n_evict
        env.check_action(obs, action)                 # raises ActionError if infeasible
        obs, *_ = env.step(action)


def test_scores_pick_the_best_candidates_and_evict_the_worst_kept() -> None:
    # map frames 0-2, candidates 3-6: upload the best 2 candidates, evict the lowest 2 of
    # the map and the uploads (an upload can be evicted when it scores lowest)
    flags = select(np.array([0.5, -1.0, 2.0, 3.0, -5.0, 1.0, 0.0]), 3, 2, 2)
    assert np.flatnonzero(flags[:, 0]).tolist() == [3, 5]
    assert np.flatnonzero(flags[:, 1]).tolist() == [0, 1]
    flags = select(np.array([0.5, 1.0, 2.0, -3.0, -5.0, -4.0, 0.0]), 3, 1, 1)
    assert np.flatnonzero(flags[:, 0]).tolist() == [6]
    assert np.flatnonzero(flags[:, 1]).tolist() == [6]


def test_untrained_actor_makes_adapts_decision(kitchen: CovisibilityDataset) -> None:
    """The correction's last layer starts near zero, so before training the actor uploads and
    evicts exactly what ADAPT does — also where ADAPT evicts a frame it has just uploaded."""
    import torch

    from twinslam.policies.learned.networks import Actor
    from twinslam.policies.learned.replay import collate

    torch.manual_seed(0)
    # the paper's rule: ADAPT's own walk stays tracked, so every slot has frames to choose
    env = _env(kitchen, slots=30, paper_rule=True)
    obs, _ = env.reset(1)
    actor = Actor(context_size(8, 2, 0))
    upload_then_evict = 0
    for _ in range(30):
        state = build_state(obs, np.zeros(0, np.float32), history=8)
        b = collate([state])
        with torch.no_grad():
            scores = actor(b.x, b.prop, b.mask, b.context)[0].numpy()
        action, _ = action_from_scores(state, scores)
        greedy = Adapt().decide(obs)
        assert action.upload == greedy.upload and action.evict == greedy.evict
        upload_then_evict += bool(set(greedy.evict) & set(greedy.upload))
        obs, *_ = env.step(greedy)
    assert upload_then_evict > 0           # the hard case was exercised


def test_relaxed_action_tends_to_the_hard_one() -> None:
    import torch

    from twinslam.policies.learned.networks import soft_flags

    rng = np.random.default_rng(2)
    n_map, n_cand = 6, 9
    x = torch.zeros(1, n_map + n_cand, NODE_FEATURES)
    x[0, :n_map, 0] = 1.0
    x[0, n_map:, 1] = 1.0
    mask = torch.ones(1, n_map + n_cand, dtype=torch.bool)
    for n_up, n_ev in [(3, 3), (0, 2), (4, 0), (9, 9)]:
        scores = torch.from_numpy(rng.normal(size=(1, n_map + n_cand)).astype(np.float32))
        soft = soft_flags(scores, x, mask, torch.tensor([n_up]), torch.tensor([n_ev]), 1e-4)
        hard = select(scores[0].numpy(), n_map, n_up, n_ev)
        assert np.allclose(soft[0].numpy(), hard, atol=1e-3)
    scores.requires_grad_(True)
    soft_flags(scores, x, mask, torch.tensor([3]), torch.tensor([3]), 0.5).sum().backward()
    assert scores.grad is not None and scores.grad.abs().sum() > 0


def test_batched_hard_action_is_select_graph_by_graph() -> None:
    """The training's batched hard action (the target actor's, and the relaxed action's
    thresholds) picks what ``select`` picks for each graph alone — padded graphs of other
    sizes, tied scores (earlier node first), nothing or everything to upload or evict."""
    import torch

    from twinslam.policies.learned.networks import hard_flags

    rng = np.random.default_rng(7)
    sizes = [(0, 5), (4, 0), (6, 9), (12, 3), (3, 12), (8, 8)]
    n = max(m + c for m, c in sizes)
    for trial in range(40):
        x = torch.zeros(len(sizes), n, NODE_FEATURES)
        mask = torch.zeros(len(sizes), n, dtype=torch.bool)
        scores = torch.zeros(len(sizes), n)
        picks = []
        for i, (m, c) in enumerate(sizes):
            x[i, :m, 0], x[i, m:m + c, 1], mask[i, :m + c] = 1.0, 1.0, True
            # few distinct values, so ties are common
            scores[i, :m + c] = torch.from_numpy(rng.integers(-2, 3, m + c).astype(np.float32))
            scores[i, m + c:] = 9.0                      # padding never chosen, whatever it scores
            n_up = int(rng.integers(0, c + 1)) if trial % 5 else c
            picks.append((m, n_up, int(rng.integers(0, m + n_up + 1))))
        flags = hard_flags(scores, x, mask, torch.tensor([p[1] for p in picks]),
                           torch.tensor([p[2] for p in picks]))
        for i, ((m, c), (_, n_up, n_ev)) in enumerate(zip(sizes, picks, strict=True)):
            expect = select(scores[i, :m + c].numpy(), m, n_up, n_ev)
            assert np.array_equal(flags[i, :m + c].numpy(), expect), (trial, i)
            assert not flags[i, m + c:].any()


def test_emulated_slot_equals_the_real_one_and_leaves_the_environment_alone(
        kitchen: CovisibilityDataset) -> None:
    env = _env(kitchen, slots=20)
    obs = _played(env, 6)
    before = env.snapshot()
    action = LatestFrameFirst().decide(obs)            # keeps the next slot tracked
    real_state, real_rate = env.rate_plan[obs.slot + 1]
    emu_obs, emu_reward, _ = env.emulate(before, action, (real_state, real_rate))
    other = 1 - real_state
    alt_obs, _, _ = env.emulate(before, action, (other, float(env.channel.rates[other])))
    obs2, reward, *_ = env.step(action)                # the environment was not disturbed
    assert emu_reward == pytest.approx(reward)
    assert emu_obs.map_frames == obs2.map_frames and emu_obs.n_upload == obs2.n_upload
    assert alt_obs.rate_state == other and alt_obs.rate_history[-1] == other
    assert alt_obs.map_frames == obs2.map_frames       # the rate does not move the map
    assert alt_obs.candidates == obs2.candidates and len(obs2.candidates) >= 8
    assert alt_obs.n_upload != obs2.n_upload           # 40 vs 80 Mbit/s: 4 vs 8 frames


def test_blended_batch_holds_i_real_tuples(kitchen: CovisibilityDataset) -> None:
    from twinslam.policies.learned.replay import ReplayBuffer, Transition, blended_batch

    obs = _played(_env(kitchen), 3)
    state = build_state(obs, np.zeros(0, np.float32), history=8)
    flags = np.zeros((state.size, 2), np.float32)
    real, artificial = ReplayBuffer(10), ReplayBuffer(10)
    for r in range(12):                                # a ring keeps the newest 10
        real.add(Transition(state, flags, float(r), state))
    rng = np.random.default_rng(0)
    assert len(real) == 10
    assert {t.reward for t in real.sample(200, rng)} == set(map(float, range(2, 12)))
    assert len(blended_batch(real, artificial, 8, 3, rng)) == 8      # no artificial yet
    for _ in range(5):
        artificial.add(Transition(state, flags, -1.0, state))
    batch = blended_batch(real, artificial, 8, 3, rng)
    assert sum(t.reward >= 0 for t in batch) == 3 and len(batch) == 8
    with pytest.raises(ValueError, match="real tuples"):
        blended_batch(real, artificial, 8, 9, rng)


def test_markov_rate_model_is_the_count_estimate() -> None:
    model = MarkovCounts(2)
    for s in [0, 0, 1, 0, 0, 0, 1, 1]:
        model.observe(s)
    # transitions from 0: 0→0 ×3, 0→1 ×2; from 1: 1→0, 1→1
    assert np.allclose(model.features([1, 0]), [0.6, 0.4])
    draws = model.sample_next([0], 20_000, np.random.default_rng(0))
    assert abs(draws.mean() - 0.4) < 0.02


def test_twin_rate_model_gives_its_latent_and_samples_states() -> None:
    from twinslam.twin.variational_twin import VariationalConfig, VariationalTwin

    model = VariationalTwin(VariationalConfig(n_states=3, retrain_every=1000))
    assert model.features([0, 1, 2]).shape == (model.feature_size,) == (16,)
    draws = model.sample_next([0, 1, 2], 50, np.random.default_rng(0))
    assert draws.shape == (50,) and set(draws.tolist()) <= {0, 1, 2}


def test_training_writes_a_policy_the_simulator_and_make_policy_run(
        kitchen: CovisibilityDataset, tmp_path: Path) -> None:
    import torch

    from twinslam.policies.learned.policy import MbrlPolicy
    from twinslam.training.trainer import AmmTrainer, TrainConfig

    config = TrainConfig(slots=40, episode_slots=20, warmup_slots=15, batch_size=8,
                         rate_model="markov", artificial_per_real=1, replay_capacity=100,
                         log_every=5, validate_every=20, validation_seeds=1,
                         validation_slots=10)
    trainer = AmmTrainer(config, kitchen)
    log = trainer.train()
    assert len(trainer.real) == 40 and len(trainer.artificial) == 40    # J = 1 per real slot
    assert log.rows and log.rows[-1]["slot"] == 40
    assert all(np.isfinite(row["critic_loss"]) for row in log.rows)
    # the actor kept is the best of the validations (slot 0 = ADAPT's decisions, 20, 40)
    assert [slot for slot, _ in trainer.validations] == [0, 20, 40]
    assert trainer.best_validation == min(v for _, v in trainer.validations)
    path = tmp_path / "amm.pt"
    trainer.save(path)
    kept = AmmTrainer(config, kitchen)
    kept.actor.load_state_dict(torch.load(path, weights_only=True)["actor"])
    assert kept.validate() == pytest.approx(trainer.best_validation)
    policy = make_policy(f"mbrl:{path}")
    assert isinstance(policy, MbrlPolicy) and policy.name == "mbrl-markov"
    plan = rollout(_env(kitchen, seed=3, slots=10), policy, 3)   # every action is checked
    assert len(plan.actions) == 10
    assert all(np.isfinite(s.objective) for s in plan.slots)
    # the edge's core plans with it too (policy:=mbrl:PATH): a slot of a made-up map
    EdgeMapperCore.warm_up(make_policy(f"mbrl:{path}"))


def test_the_papers_amm_sees_no_adapt_answer_and_trains_into_a_policy_of_its_own_name(
        kitchen: CovisibilityDataset, tmp_path: Path) -> None:
    """actor='paper': ADAPT's flag columns stay 0, the score is the GCN's alone (no prior),
    and the checkpoint runs as amm-<rate model>, beside mbrl-<rate model> (ADAPT + RL); the
    default rate model, the regime twin, can take the udt node's latent."""
    import torch

    from twinslam.policies.learned.replay import collate
    from twinslam.policies.learned.state import ADAPT_EVICT, ADAPT_UPLOAD
    from twinslam.training.trainer import AmmTrainer, TrainConfig

    env = _env(kitchen, seed=1)
    obs, _ = env.reset(1)
    state = build_state(obs, np.zeros(0, np.float32), history=8, adapt_features=False)
    assert not state.nodes[:, [ADAPT_UPLOAD, ADAPT_EVICT]].any()
    assert build_state(obs, np.zeros(0, np.float32), 8).nodes[:, ADAPT_UPLOAD].sum() == \
        obs.n_upload
    config = TrainConfig(slots=30, episode_slots=15, warmup_slots=10, batch_size=8,
                         artificial_per_real=1, replay_capacity=100,
                         log_every=5, validate_every=15, validation_seeds=1,
                         validation_slots=10, actor="paper")      # the default: regime twin
    trainer = AmmTrainer(config, kitchen)
    b = collate([trainer.state_of(obs)])
    assert torch.equal(trainer.actor(b.x, b.prop, b.mask, b.context),
                       trainer.actor.correction(b.x, b.prop, b.mask, b.context))
    trainer.train()
    assert trainer.actor.prior.item() == 0.0          # never trained: not part of the score
    path = tmp_path / "paper.pt"
    trainer.save(path)
    policy = make_policy(f"mbrl:{path}")
    assert policy.name == "amm-regime" and policy.uses_twin
    first = rollout(_env(kitchen, seed=3, slots=5), policy, 3).actions
    assert len(first) == 5
    # the regime twin is a filter over the run: a new run starts it afresh, so a run replays
    assert rollout(_env(kitchen, seed=3, slots=5), policy, 3).actions == first
    with pytest.raises(ValueError, match="unknown actor"):
        AmmTrainer(TrainConfig(actor="greedy"), kitchen)


def test_bad_policy_checkpoints_are_refused_by_name(tmp_path: Path) -> None:
    import torch

    from twinslam.policies.learned.policy import MbrlPolicy, PolicyCheckpointError

    with pytest.raises(ValueError, match="needs its checkpoint"):
        make_policy("mbrl")
    with pytest.raises(PolicyCheckpointError, match="no such policy checkpoint"):
        make_policy(f"mbrl:{tmp_path / 'missing.pt'}")
    junk = tmp_path / "junk.pt"
    junk.write_bytes(b"not a checkpoint")
    with pytest.raises(PolicyCheckpointError, match=r"junk\.pt"):
        MbrlPolicy(junk)
    other = tmp_path / "other.pt"
    torch.save({"format": "something-else"}, other)
    with pytest.raises(PolicyCheckpointError, match="not a twinslam-amm-policy-1"):
        MbrlPolicy(other)
    torch.save({"format": "twinslam-amm-policy-1", "config": {"history": 8}}, other)
    with pytest.raises(PolicyCheckpointError, match="incomplete or mismatched"):
        MbrlPolicy(other)


def test_experiment_and_train_commands_refuse_bad_arguments_by_name(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from twinslam.cli.main import main

    assert main(["experiment", "fig7", "--policy", f"UDT={tmp_path / 'none.pt'}",
                 "--out", str(tmp_path)]) == 2
    assert "none.pt: no such policy checkpoint" in capsys.readouterr().err
    assert main(["experiment", "fig9", "--policy", "just-a-path.pt"]) == 2
    assert "LABEL=CHECKPOINT" in capsys.readouterr().err
    assert main(["train", "--covis", str(tmp_path / "missing.npz"), "-o",
                 str(tmp_path / "p.pt")]) == 2
    assert "missing.npz" in capsys.readouterr().err
    assert not (tmp_path / "p.pt").exists()


def test_figure_sweeps_write_one_csv_row_per_point_and_policy_and_a_plot(
        kitchen: CovisibilityDataset, tmp_path: Path) -> None:
    from twinslam.experiments.amm import Setting, sweep

    results = sweep("figtest", [0.3, 0.7], lambda r: f"markov:N=2,ratio={r}",
                    lambda _r: Setting(runs=2, slots=6), str(COVIS), {}, tmp_path, "ratio",
                    reference=False)
    rows = (tmp_path / "figtest.csv").read_text().strip().splitlines()
    assert rows[0] == ("ratio,policy,mean_uncertainty,ci95,training_runs,episodes,lost_share,"
                       "tracked_uncertainty,best_rule,paired_vs_best_rule,paired_ci_low,"
                       "paired_ci_high")
    assert len(rows) == 1 + 2 * 4                       # 2 ratios × LFF, PU, ADAPT, RANDOM
    assert (tmp_path / "figtest.png").stat().st_size > 0
    # more 80 Mbit/s slots upload more frames: LFF's map fills faster, υ falls
    assert results[0.7]["LFF"].mean < results[0.3]["LFF"].mean


def test_a_learned_variant_is_reported_over_its_training_runs_with_every_episode(
        kitchen: CovisibilityDataset, tmp_path: Path) -> None:
    """Two untrained residual checkpoints (= ADAPT's decisions) as one variant: its mean is
    the mean over runs, the runs CSV lists every episode of every run, and the reference,
    started from all plans, is no worse than any policy in any episode."""
    import csv

    from twinslam.experiments.amm import REFERENCE, Setting, sweep
    from twinslam.training.trainer import AmmTrainer, TrainConfig

    paths = []
    for seed in (0, 1):
        trainer = AmmTrainer(TrainConfig(rate_model="markov", seed=seed, validate_every=0),
                             kitchen)
        paths.append(tmp_path / f"untrained{seed}.pt")
        trainer.save(paths[-1])
    results = sweep("figvar", [0.5], lambda r: f"markov:N=2,ratio={r}",
                    lambda _r: Setting(runs=2, slots=5), str(COVIS), {"Residual": paths},
                    tmp_path, "ratio")
    variant = results[0.5]["Residual"]
    assert variant.run_means == pytest.approx([results[0.5]["ADAPT"].mean] * 2)
    assert variant.mean == pytest.approx(results[0.5]["ADAPT"].mean) and variant.ci95 == 0.0
    with (tmp_path / "figvar_runs.csv").open() as fh:
        episodes = list(csv.DictReader(fh))
    assert len(episodes) == (3 + 1 + 2 + 1) * 2        # rules, random, 2 checkpoints, reference
    by_seed: dict[str, list[float]] = {}
    for row in episodes:
        by_seed.setdefault(row["seed"], []).append(float(row["mean_uncertainty"]))
    ref = {row["seed"]: float(row["mean_uncertainty"]) for row in episodes
           if row["policy"] == REFERENCE}
    assert all(ref[seed] <= min(values) + 1e-9 for seed, values in by_seed.items())
    summary = (tmp_path / "figvar.csv").read_text().splitlines()
    assert any(line.startswith("0.5,Residual,") and ",2,4," in line for line in summary)


def test_edge_node_with_a_missing_policy_checkpoint_says_so_and_exits(tmp_path: Path) -> None:
    from twinslam.hosts.loopback import LoopbackDomain

    missing = tmp_path / "gone.pt"
    with LoopbackDomain() as domain:
        proc = domain.spawn(["-m", "edge_mapper.node", "--ros-args", "-p", "policy:=mbrl",
                             "-p", f"policy_checkpoint:={missing}"], forks=FORKS)
        proc.wait(timeout=120)
        code, _out, err = domain.stop(proc)
    assert code == 2
    assert f"{missing}: no such policy checkpoint" in err


class _Learned:
    name, feature_size = "mbrl-variational", 4

    def __init__(self) -> None:
        self.features: list[np.ndarray] = []

    def decide(self, obs, rate_features=None):
        self.features.append(rate_features)
        return "learned"


class _Fallback:
    name = "adapt"

    def decide(self, obs):
        return "fallback"


def test_twin_fed_policy_uses_fresh_latents_and_falls_back_without_them() -> None:
    from types import SimpleNamespace

    from edge_mapper.twin_feed import TwinFedPolicy

    learned = _Learned()
    feed = TwinFedPolicy(learned, _Fallback(), max_age=1)
    assert feed.decide(SimpleNamespace(slot=0)) == "fallback" and feed.used == "adapt"
    feed.offer(3, np.array([0.5, -0.5]), np.array([1.0, 0.0]), model_version=2)
    assert feed.decide(SimpleNamespace(slot=4)) == "learned" and feed.used == "mbrl-variational"
    # [μ, log Σ] with Σ = 0 clipped, not -inf
    np.testing.assert_allclose(learned.features[-1][:3], [0.5, -0.5, 0.0])
    assert np.isfinite(learned.features[-1]).all()
    assert feed.decide(SimpleNamespace(slot=5)) == "fallback"        # two slots old: stale
    feed.offer(2, np.zeros(2), np.ones(2), 1)                          # older: not taken
    assert feed.latent is not None and feed.latent.slot == 3
    with pytest.raises(ValueError, match="a latent of 3 dimensions"):
        feed.offer(6, np.zeros(3), np.ones(3), 3)


def test_a_checkpoint_naming_the_old_udt_rate_model_loads_as_the_variational_twin() -> None:
    """Policies trained before the variational twin got its name say ``udt``: they load."""
    from twinslam.twin.registry import load_rate_model
    from twinslam.twin.variational_twin import VariationalConfig, VariationalTwin

    model = VariationalTwin(VariationalConfig(n_states=3, retrain_every=1000))
    again = load_rate_model("udt", model.state_dict())
    assert isinstance(again, VariationalTwin) and again.name == "variational"
    np.testing.assert_allclose(again.features([0, 1, 2]), model.features([0, 1, 2]))
    with pytest.raises(ValueError, match="unknown rate model"):
        load_rate_model("persistence", {})        # a baseline, never a policy's model
