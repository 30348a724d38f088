"""The causal planner ``mpc``: with a known future and a horizon over the rest of
the episode it is the exact optimum; causally it keeps Theorem 1's sizes and V_max in every
slot, leaves the real environment as it found it, and is refused where no world model exists
(the edge)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from edge_mapper.policy_control import policy_refused
from tests.test_policies_and_simulator import _small_instance
from twinslam.covisibility.dataset import CovisibilityDataset, load_covisibility
from twinslam.policies.exact_optimum import exact_optimum
from twinslam.policies.mpc import MpcConfig, MpcPlanner, parse_mpc
from twinslam.policies.plan import replay, rollout
from twinslam.policies.registry import make_policy
from twinslam.policies.world_model import FrameStream, MapManagementEnv, PredictedStream, SimConfig
from twinslam.uplink.channels import parse_channel

COVIS = Path(__file__).resolve().parents[1] / "data" / "7scenes-redkitchen-1000.covis.npz"


@pytest.fixture(scope="module")
def kitchen() -> CovisibilityDataset:
    return load_covisibility(COVIS)


KNOWN = MpcConfig(horizon=4, rates="oracle", frames="oracle", max_actions=10**6,
                  max_states=10**6)


@pytest.mark.parametrize(("seed", "device_rule"), [(0, False), (1, False), (2, False),
                                                   (3, False), (0, True), (1, True)])
def test_with_a_known_future_it_is_the_exact_optimum(seed: int, device_rule: bool) -> None:
    env = _small_instance(seed, device_rule)
    optimum = exact_optimum(env, seed).total
    plan = rollout(env, MpcPlanner(KNOWN), seed)
    assert plan.total == pytest.approx(optimum)
    assert replay(env, plan.actions, seed).total == pytest.approx(plan.total)
    causal = rollout(env, make_policy("mpc:H=2,S=3"), seed).total
    assert optimum <= causal + 1e-9                    # nothing causal beats the optimum


@pytest.mark.parametrize("spec", ["mpc:H=2,S=2", "mpc:H=2/S=2/frames=persistence",
                                  "mpc:H=2/rates=markov/S=2", "mpc:H=2/rates=last"])
def test_at_full_size_every_slot_keeps_theorem_1_and_v_max(
        kitchen: CovisibilityDataset, spec: str) -> None:
    """The environment refuses any action of the wrong sizes (check_action): a whole episode
    played is the proof; the map never exceeds V_max after any slot."""
    config = SimConfig(vmax=20, slots=8)
    env = MapManagementEnv(kitchen, parse_channel("markov:N=2", seed=5), config)
    policy = MpcPlanner(parse_mpc(spec))
    obs, _ = env.reset(5)
    policy.reset(5)
    policy.attach(env)
    for _ in range(config.slots):
        before = (env.map_frames, env.observation().slot)
        action = policy.decide(obs)
        assert (env.map_frames, env.observation().slot) == before   # imagining changed nothing
        obs, _r, _t, trunc, info = env.step(action)
        assert info["map_size"] <= config.vmax
        if trunc:
            break
    assert obs.slot == config.slots


def test_the_predicted_frames_come_from_the_frames_seen() -> None:
    data = CovisibilityDataset.from_sets([{i, i + 1} for i in range(30)])
    stream = FrameStream(data, start=10, horizon=100)
    seen = 12                                  # two slots of 6 seen: dataset frames 10..21
    persistence = PredictedStream(stream, seen, 6, data.n_frames, "persistence")
    assert persistence.dataset_index(np.arange(12, 18)).tolist() == list(range(16, 22))
    motion = PredictedStream(stream, seen, 6, data.n_frames, "motion")
    assert motion.dataset_index([11, 12, 13]).tolist() == [21, 22, 23]     # onwards
    assert motion.dataset_index([20]).tolist() == [29 - (30 - 29)]          # back at the end
    assert motion.dataset_index([3]).tolist() == [13]                       # the past as it was


def test_bad_options_and_the_edge_are_refused_by_name() -> None:
    assert parse_mpc("mpc:H=5,S=2,frames=persistence") == MpcConfig(
        horizon=5, scenarios=2, frames="persistence")
    with pytest.raises(ValueError, match="H, S, W, actions and states must be >= 1"):
        parse_mpc("mpc:H=0")
    with pytest.raises(ValueError, match="frames 'psychic'"):
        parse_mpc("mpc:frames=psychic")
    with pytest.raises(ValueError, match="mpc option 'depth=3'"):
        parse_mpc("mpc:depth=3")
    with pytest.raises(RuntimeError, match="attach"):
        MpcPlanner().decide(MapManagementEnv(
            CovisibilityDataset.from_sets([{1, 2}, {2, 3}]), parse_channel("markov:N=2"),
            SimConfig(vmax=2, slot_frames=1, slots=2)).reset(0)[0])
    with pytest.raises(ValueError, match="needs the variational twin"):
        MpcPlanner(parse_mpc("mpc:rates=variational"))       # the simulator cannot build it
    # the edge plans in a world of its own (tests/test_mpc_live.py), not in a known future
    assert policy_refused("mpc") is None
    assert "simulator-only" in (policy_refused("mpc:frames=oracle") or "")


def test_the_variational_twin_plans_and_learns_within_the_episode(
        kitchen: CovisibilityDataset) -> None:
    """``rates=variational`` (the policy registry builds the twin, torch and all): retrained
    every W slots on what the episode showed, its scenarios plan a valid episode."""
    config = SimConfig(vmax=20, slots=9)
    env = MapManagementEnv(kitchen, parse_channel("markov:N=2", seed=4), config)
    policy = make_policy("mpc:H=2/S=2/rates=variational/W=4")
    assert isinstance(policy, MpcPlanner)
    plan = rollout(env, policy, 4)
    assert len(plan.actions) == config.slots
    twin = policy._twin
    assert twin is not None and twin.version == 2        # retrained at slots 4 and 8
    assert replay(env, plan.actions, 4).total == pytest.approx(plan.total)
