"""The simulator's edge with an archive: evicted keyframes kept, restores scored, planned and
made with the future known (twinslam.policies.restoring)."""

from __future__ import annotations

import csv
import dataclasses
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from twinslam.cli.arguments import DEFAULT_CHANNEL
from twinslam.covisibility.dataset import CovisibilityDataset, load_covisibility
from twinslam.policies.actions import ActionError, MapAction, SlotObservation
from twinslam.policies.exact_optimum import exact_optimum
from twinslam.policies.mpc import MpcConfig, MpcPlanner
from twinslam.policies.plan import rollout
from twinslam.policies.reference import ReferencePlanner
from twinslam.policies.registry import make_policy
from twinslam.policies.restoring import RestoringPolicy
from twinslam.policies.rules import LatestFrameFirst, PeriodicalUploading
from twinslam.policies.world_model import MapManagementEnv, SimConfig
from twinslam.uplink.channels import TraceChannel, parse_channel

REPO = Path(__file__).resolve().parents[1]
#: a corridor of 40 frames: frame i sees points 3i … 3i+59, so frames k apart share 60 - 3k
#: points: with 35 needed, a frame tracks on a keyframe at most 8 frames away
CORRIDOR = CovisibilityDataset.from_sets([np.arange(3 * i, 3 * i + 60) for i in range(40)])
SLOTS = 18
#: 40 Mbit/s (4 uploads a slot) on the way out, 5 (none) on the way back: the map can follow
#: the camera back only with keyframes it kept
RATES = np.where(np.arange(SLOTS + 2) < 10, 40.0, 5.0)


def walk(archive: int, restores: int = 2) -> MapManagementEnv:
    """The corridor walked from its first frame to its end and back, 4 frames a slot, a map
    of 3 keyframes; lost with fewer than 35 shared points, a slot's first frame tracked on
    the map before the update."""
    config = SimConfig(vmax=3, slot_frames=4, slots=SLOTS, alpha_mbit=5.0, d_req_s=0.5,
                       min_shared=35, update_lag_frames=1, start=0,
                       archive_keyframes=archive, restore_keyframes=restores if archive else 0)
    channel = TraceChannel.from_samples(np.arange(SLOTS + 2) * 2.0, RATES, 2, (5.0, 40.0),
                                        start_s=0.0)
    return MapManagementEnv(CORRIDOR, channel, config)


def test_the_archive_keeps_what_the_map_evicts_up_to_its_size() -> None:
    env = walk(archive=4)
    obs, _ = env.reset(0)
    evicted: list[int] = []
    for _ in range(6):
        action = LatestFrameFirst().decide(obs)
        evicted += sorted(action.evict)
        obs, *_ = env.step(action)
    assert len(evicted) > 4
    assert obs.archive == evicted[-4:]            # the oldest evictions left first
    assert not set(obs.archive) & set(obs.map_frames)
    paper = walk(archive=0)
    obs, _ = paper.reset(0)
    for _ in range(6):
        obs, *_ = paper.step(LatestFrameFirst().decide(obs))
    assert obs.archive == [] and obs.n_restore == 0      # the paper's edge forgets


def test_a_restore_comes_back_and_evicts_in_exchange_or_is_refused() -> None:
    env = walk(archive=10, restores=1)
    obs, _ = env.reset(0)
    for _ in range(4):
        obs, *_ = env.step(LatestFrameFirst().decide(obs))
    base = LatestFrameFirst().decide(obs)
    back = obs.archive[0]
    kept = sorted((set(obs.map_frames) | set(base.upload)) - set(base.evict))
    assert len(kept) == 3 and obs.evictions_with(1) == obs.n_evict + 1
    snap = env.snapshot()
    with pytest.raises(ActionError, match="evict"):            # the map would hold 4
        env.step(MapAction(base.upload, base.evict, [back]))
    with pytest.raises(ActionError, match="not in the archive"):
        env.step(MapAction(base.upload, [*base.evict, kept[0]], [kept[1]]))
    with pytest.raises(ActionError, match="at most 1"):
        env.step(MapAction(base.upload, [*base.evict, *kept[:2]], obs.archive[:2]))
    env.restore(snap)
    _obs, _r, _t, _tr, info = env.step(MapAction(base.upload, sorted([*base.evict, kept[0]]),
                                                 [back]))
    assert info["restored"] == 1
    assert back in env.map_frames and len(env.map_frames) == 3
    assert kept[0] in env.observation().archive and back not in env.observation().archive
    env.restore(snap)                           # a snapshot holds the archive as it was
    assert env.observation().archive == obs.archive


def test_the_rules_evict_the_keyframes_longest_in_the_map_not_the_oldest_ids() -> None:
    """A keyframe restored last slot (id 2) is old by capture but new to the map; LFF and PU
    evict the keyframes that entered the map first. Without the entry order — the paper's
    map, which only adds uploads — the oldest ids go, as the paper's rules do."""
    def obs(entered: list[int] | None) -> SlotObservation:
        return SlotObservation(5, [2, 10, 11, 12], [20, 21, 22], 1, 2, 5.0, 0, [0], 2,
                               entered=entered)

    for rule in (LatestFrameFirst(), PeriodicalUploading()):
        assert rule.decide(obs([10, 11, 2, 12])).evict == [10, 11]
        assert rule.decide(obs(None)).evict == [2, 10]


class _ById(LatestFrameFirst):
    """LFF reading ids as the map's order (the rule before it read the entry order)."""

    def decide(self, obs: SlotObservation) -> MapAction:
        return super().decide(dataclasses.replace(obs, entered=None))


def _evicted_next_slot(policy: LatestFrameFirst) -> tuple[int, int]:
    """(restores of three episodes of the bundled 7-Scenes walk forward and back as the
    restores' yardstick runs them — V_max 15, 3 restores a slot — those evicted again at the
    very next slot)."""
    covis = load_covisibility(REPO / "data" / "7scenes-redkitchen-1000.covis.npz")
    config = SimConfig(vmax=15, slots=34, start=0, archive_keyframes=500, restore_keyframes=3)
    restores = next_slot = 0
    for seed in range(3):
        env = MapManagementEnv(covis, parse_channel(DEFAULT_CHANNEL, seed=seed), config)
        actions = rollout(env, RestoringPolicy(policy), seed).actions
        made = [(k, kf) for k, action in enumerate(actions) for kf in action.restore]
        restores += len(made)
        next_slot += sum(k + 1 < len(actions) and kf in actions[k + 1].evict for k, kf in made)
    return restores, next_slot


def test_a_restored_keyframe_is_not_the_first_the_map_evicts_again() -> None:
    """A restore enters the map as an upload does, at its slot: LFF's next decision evicts
    keyframes that were in the map before it (the restore rule's own exchanges may still
    take it). Read by id, the restore was the oldest and went first."""
    restores, next_slot = _evicted_next_slot(LatestFrameFirst())
    by_id, by_id_next = _evicted_next_slot(_ById())
    print(f"\nrestores evicted the next slot: {next_slot} of {restores} by entry, "
          f"{by_id_next} of {by_id} by id")
    assert restores and next_slot <= 0.5 * restores
    assert by_id_next >= 0.8 * by_id


def test_restoring_loses_fewer_frames_on_the_way_back_and_is_the_policy_without_archive(
        ) -> None:
    lff = rollout(walk(archive=20), LatestFrameFirst(), 0)
    restoring = rollout(walk(archive=20), RestoringPolicy(LatestFrameFirst()), 0)
    assert restoring.restored > 0 and lff.restored == 0
    assert restoring.tally.lost_share < lff.tally.lost_share
    without = rollout(walk(archive=0), RestoringPolicy(LatestFrameFirst()), 0)
    assert without.restored == 0
    assert without.actions == rollout(walk(archive=0), LatestFrameFirst(), 0).actions
    assert make_policy("restore:lff").name == "restore:lff"
    with pytest.raises(ValueError, match="restore:POLICY"):
        make_policy("restore:")


def test_the_reference_and_a_known_future_planner_restore_and_lose_least() -> None:
    restoring = rollout(walk(archive=20), RestoringPolicy(LatestFrameFirst()), 0)
    reference = ReferencePlanner(swap_evaluations=50).plan(walk(archive=20), 0,
                                                           known=[restoring])
    assert reference.restored > 0 and reference.total <= restoring.total + 1e-9
    forgetting = ReferencePlanner(swap_evaluations=50).plan(walk(archive=0), 0)
    assert reference.tally.lost_share < forgetting.tally.lost_share
    planner = MpcPlanner(MpcConfig(horizon=2, rates="oracle", frames="oracle"))
    planned = rollout(walk(archive=20), planner, 0)
    assert planned.restored > 0
    assert planned.tally.lost_share < rollout(walk(archive=20), LatestFrameFirst(),
                                              0).tally.lost_share


def test_the_exact_optimum_refuses_a_world_with_restores() -> None:
    """It searches uploads and evictions only: with restores it would not be the optimum."""
    with pytest.raises(ValueError, match="would not be the optimum"):
        exact_optimum(walk(archive=20), 0)


def test_restores_without_an_archive_are_refused() -> None:
    with pytest.raises(ValueError, match="needs an archive"):
        SimConfig(restore_keyframes=2)
    with pytest.raises(ValueError, match=">= 0"):
        SimConfig(archive_keyframes=-1)


def test_sim_scores_restores_and_refuses_them_without_an_archive(tmp_path: Path) -> None:
    out = tmp_path / "runs.csv"
    proc = subprocess.run([sys.executable, "-m", "twinslam.cli.main", "sim", "--covis",
                           "geometric:300", "--policy", "lff,restore:lff", "--slots", "12",
                           "--seeds", "1", "--vmax", "8", "--walk-start", "0",
                           "--archive-keyframes", "100", "--restore-keyframes", "2",
                           "--csv", str(out)], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert "restored/run" in proc.stdout and "an archive of 100 keyframes" in proc.stdout
    restored = {r["policy"]: int(r["restored"]) for r in csv.DictReader(out.open())}
    assert restored["lff"] == 0 and restored["restore:lff"] > 0
    bad = subprocess.run([sys.executable, "-m", "twinslam.cli.main", "sim", "--covis",
                          "geometric:300", "--restore-keyframes", "2"],
                         capture_output=True, text=True, timeout=120)
    assert bad.returncode == 2 and "needs an archive" in bad.stderr
