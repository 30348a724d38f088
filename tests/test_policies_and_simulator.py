"""Policies, the gym-style simulator, the reference plan and the exact optimum (paper §VII)."""

from __future__ import annotations

import csv
import itertools
import subprocess
import sys

import numpy as np
import pytest

from twinslam.covisibility import dataset as covisibility_module
from twinslam.covisibility.dataset import (
    CovisibilityDataset,
    load_covisibility,
    save_covisibility,
)
from twinslam.covisibility.geometric import geometric_covisibility
from twinslam.policies.actions import ActionError, MapAction
from twinslam.policies.exact_optimum import InstanceTooLarge, exact_optimum
from twinslam.policies.plan import replay, rollout
from twinslam.policies.reference import ReferencePlanner
from twinslam.policies.registry import make_policy
from twinslam.policies.rules import Adapt, greedy_additions, greedy_removals
from twinslam.policies.world_model import FrameStream, MapManagementEnv, SimConfig
from twinslam.simulator.lower_bound import episode_lower_bound, slot_lower_bounds
from twinslam.uncertainty.map_uncertainty import UncertaintyTally
from twinslam.uncertainty.naive_greedy import naive_greedy
from twinslam.uplink.channels import MarkovChannel, parse_channel, state_rates


@pytest.fixture(scope="module")
def room() -> CovisibilityDataset:
    return geometric_covisibility(n_frames=400, n_points=2000, seed=3)


def _random_universe(rng: np.random.Generator, n: int, clusters: int = 1) -> np.ndarray:
    """Weights of n frames with random point sets drawn from a moving window of points; with
    ``clusters`` > 1 each frame's window is also shifted to one of that many disjoint regions
    (at random), so maps and unions are often disconnected and some candidates bridge."""
    region = rng.integers(0, clusters, n) * 10_000
    sets = [set((region[i] + rng.choice(np.arange(i * 3, i * 3 + 60), 30, replace=False)
                 ).tolist()) for i in range(n)]
    return CovisibilityDataset.from_sets(sets).weights(np.arange(n), np.arange(n))


@pytest.mark.parametrize("clusters", [1, 2, 3])
@pytest.mark.parametrize("seed", range(12))
def test_incremental_adapt_picks_what_the_naive_greedy_picks(seed: int, clusters: int) -> None:
    rng = np.random.default_rng(seed)
    n_map, n_cand = int(rng.integers(0, 12)), int(rng.integers(4, 14))
    w = _random_universe(rng, n_map + n_cand, clusters)
    n_add = int(rng.integers(1, min(n_cand, 6) + 1))
    n_remove = int(rng.integers(0, n_map + n_add))
    map_idx, cand_idx = list(range(n_map)), list(range(n_map, n_map + n_cand))
    picks = greedy_additions(w[np.ix_(map_idx, map_idx)], w[np.ix_(cand_idx, map_idx)],
                             w[np.ix_(cand_idx, cand_idx)], n_add)
    added = [cand_idx[i] for i in picks]
    union = sorted(map_idx + added)
    removed = [union[i] for i in greedy_removals(w[np.ix_(union, union)], n_remove)]
    ref_added, ref_removed = naive_greedy(w, map_idx, cand_idx, n_add, n_remove)
    assert added == ref_added
    assert removed == ref_removed


@pytest.mark.parametrize("start", [0, 120, 250])
def test_pruned_adapt_equals_naive_greedy_at_full_size(room: CovisibilityDataset,
                                                       start: int) -> None:
    """V_max 45, 60 candidates, 8 up / 8 evict on dense room windows: most candidates are
    skipped by the bounds here, and the picks must still be the naive greedy's."""
    idx = np.arange(start, start + 105)
    w = room.weights(idx, idx)
    np.fill_diagonal(w, 0)
    map_idx, cand_idx = list(range(45)), list(range(45, 105))
    picks = greedy_additions(w[np.ix_(map_idx, map_idx)], w[np.ix_(cand_idx, map_idx)],
                             w[np.ix_(cand_idx, cand_idx)], 8)
    added = [cand_idx[i] for i in picks]
    union = sorted(map_idx + added)
    removed = [union[i] for i in greedy_removals(w[np.ix_(union, union)], 8)]
    assert (added, removed) == naive_greedy(w, map_idx, cand_idx, 8, 8)


def test_policies_respect_theorem1_and_differ(room: CovisibilityDataset) -> None:
    config = SimConfig(vmax=20, slots=12)
    uploads = {}
    for name in ("lff", "pu", "adapt", "random"):
        env = MapManagementEnv(room, parse_channel("markov:N=2", seed=1), config)
        obs, _ = env.reset(seed=1)
        policy = make_policy(name)
        sets = []
        for _ in range(config.slots):
            action = policy.decide(obs)
            assert len(action.upload) == obs.n_upload
            assert len(action.evict) == obs.n_evict
            obs, reward, _t, _trunc, info = env.step(action)
            assert info["map_size"] <= config.vmax
            assert np.isfinite(reward)
            sets.append(tuple(action.upload))
        uploads[name] = sets
    assert len({tuple(v) for v in uploads.values()}) == 4


def test_env_refuses_actions_that_break_the_slot_constraints(room: CovisibilityDataset) -> None:
    env = MapManagementEnv(room, parse_channel("markov:N=2"), SimConfig(vmax=10, slots=3))
    obs, _ = env.reset(seed=0)
    with pytest.raises(ActionError, match="Theorem 1"):
        env.step(MapAction(obs.candidates[:obs.n_upload + 1], []))
    with pytest.raises(ActionError, match=r"not frames of this slot"):
        env.step(MapAction([10_000 + i for i in range(obs.n_upload)], []))


def test_reference_is_never_worse_than_the_policies_it_starts_from(
        room: CovisibilityDataset) -> None:
    config = SimConfig(vmax=15, slots=6)
    for seed in (0, 1):
        env = MapManagementEnv(room, parse_channel("markov:N=2", seed=seed), config)
        reference = ReferencePlanner(beam=3, perturbations=2, swap_evaluations=20)
        total = reference.plan(env, seed).total
        for name in ("lff", "pu", "adapt"):
            env = MapManagementEnv(room, parse_channel("markov:N=2", seed=seed), config)
            policy_total = rollout(env, make_policy(name), seed).total
            assert total <= policy_total + 1e-9, f"{name} beat the reference on seed {seed}"


def test_reference_local_search_improves_on_a_plan_and_keeps_it_valid(
        room: CovisibilityDataset) -> None:
    """Swaps carried into later slots keep every action valid (replay re-checks them), and
    the search finds something better than LFF's plan on the room."""
    config = SimConfig(vmax=15, slots=10)
    env = MapManagementEnv(room, parse_channel("markov:N=2", seed=2), config)
    lff = rollout(env, make_policy("lff"), 2)
    improved = ReferencePlanner(swap_evaluations=150)._local_search(env, 2, lff)
    assert improved.total < lff.total
    assert replay(env, improved.actions, 2).total == pytest.approx(improved.total)


def _small_instance(seed: int, device_rule: bool = False) -> MapManagementEnv:
    """≤ 6 frames a slot, V_max 4, 4 slots, 1–2 uploads: small enough for the exact optimum;
    frames with overlapping point windows so that maps, bridges and lost frames all occur.
    Scored by the paper's rule, or (``device_rule``) by the device's shape of it at this
    world's scale: 3 shared points needed, a slot's first 2 frames on the map before."""
    rng = np.random.default_rng(seed)
    sets = [set(rng.choice(np.arange(i, i + 14), 8, replace=False).tolist())
            for i in range(0, 120, 2)]
    data = CovisibilityDataset.from_sets(sets)
    shape = dict(vmax=4, slot_frames=6, slots=4, alpha_mbit=5.0, d_req_s=0.25)
    config = (SimConfig(min_shared=3, update_lag_frames=2, **shape) if device_rule
              else SimConfig.paper_rule(**shape))
    return MapManagementEnv(data, MarkovChannel(state_rates(2, 20.0, 40.0), seed=seed), config)


@pytest.mark.parametrize(("seed", "device_rule"), [(0, False), (1, False), (2, False),
                                                   (3, False), (0, True), (1, True)])
def test_no_policy_nor_the_reference_beats_the_exact_optimum(seed: int,
                                                            device_rule: bool) -> None:
    env = _small_instance(seed, device_rule)
    optimum = exact_optimum(env, seed)
    assert replay(env, optimum.actions, seed).total == pytest.approx(optimum.total)
    scores = {name: rollout(env, make_policy(name), seed).total
              for name in ("lff", "pu", "adapt", "random")}
    scores["reference"] = ReferencePlanner(beam=4, swap_evaluations=50).plan(env, seed).total
    bound = episode_lower_bound(env, seed)
    print(f"\nseed {seed}: optimum {optimum.total:.1f}, bound {bound:.1f}, " +
          ", ".join(f"{name} {total:.1f}" for name, total in scores.items()))
    for name, total in scores.items():
        assert optimum.total <= total + 1e-9, f"{name} beat the exact optimum"
    assert bound <= optimum.total
    # not vacuous: on these instances the rule policies leave something on the table
    assert scores["adapt"] > optimum.total + 1.0


def test_the_hadamard_bound_lies_below_every_policy_at_full_size(
        room: CovisibilityDataset) -> None:
    config = SimConfig(vmax=45, slots=12)
    for seed in (0, 1):
        env = MapManagementEnv(room, parse_channel("markov:N=2", seed=seed), config)
        bounds = slot_lower_bounds(env, seed)
        for name in ("lff", "adapt", "random"):
            plan = rollout(env, make_policy(name), seed)
            assert all(b <= u + 1e-9 for b, u in zip(bounds, plan.objectives, strict=True)), name
    env.config = SimConfig(log_det_pi=1.0)
    with pytest.raises(ValueError, match="Π = I"):
        slot_lower_bounds(env, 0)


def test_exact_optimum_equals_brute_force_on_a_tiny_case() -> None:
    sets = [set(range(i, i + 6)) for i in range(0, 40, 2)]
    data = CovisibilityDataset.from_sets(sets)
    config = SimConfig.paper_rule(vmax=3, slot_frames=4, slots=3, alpha_mbit=5.0, d_req_s=0.25)
    channel = MarkovChannel(state_rates(2, 20.0, 40.0), seed=0)
    env = MapManagementEnv(data, channel, config)
    plan = exact_optimum(env, seed=0)

    # Independent brute force over every action sequence.
    best = np.inf

    def search(snapshot, depth: int, total: float) -> None:
        nonlocal best
        env.restore(snapshot)
        obs = env.observation()
        for up in itertools.combinations(obs.candidates, obs.n_upload):
            pool = sorted(obs.map_frames + list(up))
            for ev in itertools.combinations(pool, obs.n_evict):
                env.restore(snapshot)
                _o, reward, _t, trunc, _i = env.step(MapAction(list(up), list(ev)))
                if trunc:
                    best = min(best, total - reward)
                else:
                    search(env.snapshot(), depth + 1, total - reward)

    env.reset(seed=0)
    search(env.snapshot(), 0, 0.0)
    assert plan.total == pytest.approx(best)


def test_exact_optimum_refuses_an_instance_too_large() -> None:
    env = _small_instance(0)
    with pytest.raises(InstanceTooLarge, match="too large"):
        exact_optimum(env, 0, max_maps=10)


def test_adapt_lowers_the_tracked_frames_uncertainty_on_the_room_model(
        room: CovisibilityDataset) -> None:
    """ADAPT keeps the keyframes that make the map most informative: the frames it tracks
    score a lower u than LFF's. On this fast walk it also loses more frames (a lost frame
    cannot be uploaded, so a spread-out map does not catch up): the three figures of
    docs/architecture.md §2, printed."""
    config = SimConfig(vmax=20, slots=20)
    figures = {}
    for name in ("lff", "adapt"):
        tally = UncertaintyTally()
        for seed in range(3):
            env = MapManagementEnv(room, parse_channel("markov:N=2", seed=seed), config)
            tally = UncertaintyTally.of([tally, *rollout(env, make_policy(name), seed).slots])
        figures[name] = (tally.mean, tally.lost_share, tally.tracked_uncertainty)
    print("mean υ, lost share, υ tracked over 3 seeds: " + ", ".join(
        f"{n} {m:.1f} / {lost:.1%} / {t:.1f}" for n, (m, lost, t) in figures.items()))
    assert figures["adapt"][2] < figures["lff"][2]


def test_a_lost_frame_is_never_an_upload_candidate(room: CovisibilityDataset) -> None:
    env = MapManagementEnv(room, parse_channel("markov:N=2", seed=0),
                           SimConfig(vmax=20, slots=12, min_shared=30, update_lag_frames=20))
    obs, _ = env.reset(0)
    assert obs.candidates == env.slot_frames(0), "slot 0 tracks on the start-up map"
    lost_seen = 0
    policy = make_policy("lff")
    for _ in range(11):
        obs, _r, _t, _trunc, info = env.step(policy.decide(obs))
        frames = env.slot_frames(obs.slot)
        lost = {f for f, gone in zip(frames, info["lost"], strict=True) if gone}
        assert set(obs.candidates) == set(frames) - lost
        assert info["uncertainty"].n_lost == len(lost)
        lost_seen += len(lost)
        if lost and obs.n_upload:
            with pytest.raises(ActionError, match="not frames of this slot"):
                env.check_action(obs, MapAction([min(lost), *obs.candidates[1:obs.n_upload]],
                                                list(obs.map_frames[:obs.n_evict])))
    assert lost_seen > 0


def _line_world() -> CovisibilityDataset:
    """Frames 0..7: frame i sees points 10i..10i+29 (its neighbours share 20, 10, 0)."""
    return CovisibilityDataset.from_sets([np.arange(10 * i, 10 * i + 30) for i in range(8)])


def test_the_first_frames_of_a_slot_are_tracked_against_the_map_before_the_update() -> None:
    """Slots of 2 frames, V_max 1: slot 0 keeps frame 1, slot 1 replaces it with frame 2.
    Frame i sees points 10i..10i+29, so neighbours share 20 points, frames two apart 10."""
    data = _line_world()

    def lost(lag: int, min_shared: int) -> tuple[int, int]:
        env = MapManagementEnv(data, parse_channel("markov:N=2", seed=0),
                               SimConfig(vmax=1, slot_frames=2, slots=2, alpha_mbit=1e-3,
                                         min_shared=min_shared, update_lag_frames=lag))
        env.reset(0)
        env.stream = FrameStream(data, start=0, horizon=8)        # frames 0..7 in order
        env.restore(([], np.zeros((0, 0)), 0, [0, 1], [], 0.0, {}))
        _, _, _, _, first = env.step(MapAction([1], []))           # map {1}; next: 2, 3
        _, _, _, _, second = env.step(MapAction([2], [1]))         # map {2}; next: 4, 5
        return int(first["uncertainty"].n_lost), int(second["uncertainty"].n_lost)
    # the paper's rule: frame 3 shares 10 points with {1}; frame 4 shares 10 with {2}, 5 none
    assert lost(lag=0, min_shared=1) == (0, 1)
    # ten shared points are too few for a threshold of 15
    assert lost(lag=0, min_shared=15) == (1, 2)
    # frame 4, the first of its slot, still tracks with {1}: nothing shared. No lag before
    # the first update (the device's start-up map)
    assert lost(lag=1, min_shared=1) == (0, 2)


@pytest.mark.parametrize("dense", [True, False])
def test_a_slot_scores_alike_with_or_without_the_kept_factorisation(
        room: CovisibilityDataset, dense: bool, monkeypatch: pytest.MonkeyPatch) -> None:
    """A slot's first frames are scored against the factorisation kept from the previous
    slot's scoring; forgetting it before every step — and jumping around with
    emulate and restore, as training does — gives the same rewards, lost frames and maps,
    with dense weights and with sparse ones (a dataset too large to keep dense)."""
    if not dense:
        monkeypatch.setattr(covisibility_module, "DENSE_LIMIT", 0)
    data = CovisibilityDataset(room.point_offsets, room.point_ids)
    assert data.dense == dense

    def play(forget: bool) -> list[tuple[float, list[int], list[bool]]]:
        env = MapManagementEnv(data, parse_channel("markov:N=2", seed=3),
                               SimConfig(vmax=12, slot_frames=10, slots=12))
        obs, _ = env.reset(3)
        policy, out = make_policy("adapt"), []
        for _ in range(12):
            before = env.snapshot()
            action = policy.decide(obs)
            if obs.slot % 3 == 1:                       # an artificial slot in between
                env.emulate(before, action, (0, float(env.channel.rates[0])))
            if forget:
                env._factor = None
            obs, reward, _, _, info = env.step(action)
            out.append((reward, obs.map_frames, info["lost"].tolist()))
        return out
    assert play(forget=False) == play(forget=True)


def test_covisibility_file_round_trip_and_errors(tmp_path, room: CovisibilityDataset) -> None:
    path = tmp_path / "covis.npz"
    save_covisibility(path, room)
    back = load_covisibility(path)
    idx = np.arange(0, 400, 37)
    assert np.array_equal(back.weights(idx, idx), room.weights(idx, idx))
    with pytest.raises(ValueError, match="does not exist"):
        load_covisibility(tmp_path / "missing.npz")
    bad = tmp_path / "bad.npz"
    bad.write_bytes(b"not a zip")
    with pytest.raises(ValueError, match=r"bad\.npz"):
        load_covisibility(bad)
    # a file cut off part-way (a process killed while writing one): a clear error, not zlib's
    cut = tmp_path / "cut.npz"
    cut.write_bytes(path.read_bytes()[: path.stat().st_size // 2])
    with pytest.raises(ValueError, match=r"cut\.npz: not a readable covisibility file"):
        load_covisibility(cut)
    # writing leaves the finished file alone, nothing beside it
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.npz", "covis.npz", "cut.npz"]


def test_a_stretch_of_frames_is_a_dataset_of_its_own(room: CovisibilityDataset) -> None:
    part = room.stretch(100, 250)
    assert part.n_frames == 150
    idx = np.arange(0, 150, 13)
    assert np.array_equal(part.weights(idx, idx), room.weights(idx + 100, idx + 100))
    with pytest.raises(ValueError, match="not a stretch"):
        room.stretch(300, 500)


@pytest.mark.slow(seconds=25)
def test_sim_cli_prints_a_table_and_writes_csv(tmp_path) -> None:
    """One CSV row per run; a lost frame scores 0, so mean = (1 - lost) · tracked in every
    row (V_max 8 on the room loses frames, so the identity is not 0 = 0)."""
    out = tmp_path / "res.csv"
    proc = subprocess.run([sys.executable, "-m", "twinslam.cli.main", "sim", "--policy",
                           "lff,adapt,random,reference", "--covis", "geometric:300", "--slots",
                           "5", "--seeds", "2", "--vmax", "8", "--csv", str(out)],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert "adapt" in proc.stdout and "ci95" in proc.stdout and "gap to reference" in proc.stdout
    rows = list(csv.DictReader(out.read_text().splitlines()))
    assert [(r["policy"], r["seed"]) for r in rows] == [
        (p, s) for p in ("lff", "adapt", "random", "reference") for s in ("0", "1")]
    for r in rows:
        mean, lost, tracked = (float(r[k]) for k in ("mean_uncertainty", "lost_share",
                                                     "tracked_uncertainty"))
        assert mean == pytest.approx((1 - lost) * tracked, rel=1e-5)   # 6-digit rounding
    assert any(float(r["lost_share"]) > 0 for r in rows)
    assert "[2/2] seed 1" in proc.stdout                  # a progress line per seed
    # the seeds on two worker processes: the same rows, whichever process ran which seed
    parallel = tmp_path / "parallel.csv"
    proc = subprocess.run([sys.executable, "-m", "twinslam.cli.main", "sim", "--policy",
                           "lff,adapt,random,reference", "--covis", "geometric:300", "--slots",
                           "5", "--seeds", "2", "--vmax", "8", "--csv", str(parallel),
                           "--jobs", "2"], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert parallel.read_text() == out.read_text()
    bad = subprocess.run([sys.executable, "-m", "twinslam.cli.main", "sim", "--covis",
                          "geometric:300", "--devices", "2", "--jobs", "2"],
                         capture_output=True, text=True, timeout=120)
    assert bad.returncode == 2 and "--devices" in bad.stderr
    bad = subprocess.run([sys.executable, "-m", "twinslam.cli.main", "sim", "--covis",
                          "geometric:300", "--channel", "wifi:fast"],
                         capture_output=True, text=True, timeout=120)
    assert bad.returncode == 2 and "unknown channel" in bad.stderr
    bad = subprocess.run([sys.executable, "-m", "twinslam.cli.main", "sim", "--covis",
                          "geometric:300:x"], capture_output=True, text=True, timeout=120)
    assert bad.returncode == 2 and "geometric[:FRAMES[:SEED]]" in bad.stderr


def test_adapt_policy_object_is_usable_by_name() -> None:
    assert isinstance(make_policy("adapt"), Adapt)
    with pytest.raises(ValueError, match="unknown policy"):
        make_policy("magic")


def test_training_runs_of_one_learned_variant_get_rows_of_their_own() -> None:
    """`twinslam sim --policy mbrl:a.pt,mbrl:b.pt`: both are "amm-regime-real" by kind; the
    table must tell them apart (by checkpoint) and leave unique labels alone."""
    from twinslam.simulator.evaluation import distinct_labels

    labels = distinct_labels({"lff": "lff", "mbrl:runs/amm_s0.pt": "amm-regime-real",
                              "mbrl:runs/amm_s1.pt": "amm-regime-real",
                              "mbrl:other.pt": "amm-variational", "reference": "reference"})
    assert labels == {"lff": "lff", "mbrl:runs/amm_s0.pt": "amm-regime-real (amm_s0)",
                      "mbrl:runs/amm_s1.pt": "amm-regime-real (amm_s1)",
                      "mbrl:other.pt": "amm-variational", "reference": "reference"}
