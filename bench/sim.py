"""Simulator benchmark: slots/s per policy at V_max 45, F 60, and ADAPT's
incremental greedy against a naive greedy that recomputes every determinant.

A slot is decide + map update + the reward υ_k (eq. 8: 60 log-determinants of 45x45 reduced
Laplacians). Both the full slot rate and the decision-only rate are printed, because the
reward's cost is the same for every policy and bounds them all. Each policy runs under the
device's rule of a lost frame (``twinslam/slot_protocol/lost_frame_rule.py``: shared-point counts, a
second scoring of the slot's first frames against the map before the update) and under the
paper's, side by side in one run (``--rule``); their trajectories differ (a lost frame is not
uploaded under the device's rule), so the decisions differ too.

    python -m bench.sim [--covis FILE|room] [--slots 100] [--repeats 5] [--rule both]
                        [--baseline COMMIT --rounds 3]

Every slots/s is also printed divided by the gauge's M Python loop steps/s taken beside it
(the gauge's unit: the machine's phase cancels). ``--baseline COMMIT`` runs that commit's
simulator (a temporary git worktree, this venv) and the working tree's alternately, round by
round, the same policies and rules, and prints both side by side.
"""

from __future__ import annotations

import argparse
import platform
import statistics
import time
from pathlib import Path

import numpy as np

from bench.baseline import add_baseline_options, alternately, run_in_tree
from bench.fleet import device_slots_per_s as fleet_device_slots_per_s
from bench.gauge import cpu_gauge, python_steps_per_s
from twinslam.covisibility.dataset import CovisibilityDataset, load_covisibility
from twinslam.covisibility.geometric import geometric_covisibility
from twinslam.policies.registry import make_policy
from twinslam.policies.rules import greedy_additions, greedy_removals
from twinslam.policies.world_model import MapManagementEnv, SimConfig
from twinslam.uncertainty import laplacian_kernels as kernels
from twinslam.uncertainty.laplacian_factorization import PIVOT_RTOL
from twinslam.uncertainty.naive_greedy import naive_greedy
from twinslam.uplink.channels import parse_channel

REAL_COVIS = Path(__file__).resolve().parents[1] / "data" / "7scenes-redkitchen-1000.covis.npz"


def slots_per_second(dataset: CovisibilityDataset, name: str, slots: int, repeats: int,
                     paper_rule: bool = False) -> tuple[float, float]:
    """Median over ``repeats`` runs of (slots/s, decisions/s): this VM's speed drifts by tens
    of percent between runs, and a median of short runs is steadier than one long run."""
    runs = [_one_run(dataset, name, slots, paper_rule) for _ in range(repeats)]
    return (float(np.median([r[0] for r in runs])), float(np.median([r[1] for r in runs])))


def _one_run(dataset: CovisibilityDataset, name: str, slots: int, paper_rule: bool
             ) -> tuple[float, float]:
    config = (SimConfig.paper_rule(vmax=45, slot_frames=60, slots=slots + 30) if paper_rule
              else SimConfig(vmax=45, slot_frames=60, slots=slots + 30))
    env = MapManagementEnv(dataset, parse_channel("markov:N=2", seed=0), config)
    policy = make_policy(name)
    obs, _ = env.reset(seed=0)
    for _ in range(30):  # fill the map to V_max first
        obs, *_ = env.step(policy.decide(obs))
    decide_s = 0.0
    start = time.perf_counter()
    for _ in range(slots):
        t0 = time.perf_counter()
        action = policy.decide(obs)
        decide_s += time.perf_counter() - t0
        obs, *_ = env.step(action)
    total = time.perf_counter() - start
    return slots / total, slots / decide_s


def reward_kernel_seconds(dataset: CovisibilityDataset, slots: int = 100) -> float:
    """Median seconds a slot spends in the reward's arithmetic alone under the device's rule:
    one factorisation of the new map with the late frames scored against it, and the early
    frames scored against the map before (whose factorisation the slot before kept) — the
    kernels and nothing around them, on the maps and frames an LFF episode meets. A floor
    under any slot loop built on these kernels."""
    config = SimConfig(vmax=45, slot_frames=60, slots=slots + 30)
    env = MapManagementEnv(dataset, parse_channel("markov:N=2", seed=0), config)
    policy = make_policy("lff")
    obs, _ = env.reset(seed=0)
    lag, dense = config.lag_frames, dataset.dense_weights
    times = []
    for k in range(slots + 30):
        before = env.stream.dataset_index(obs.map_frames)
        obs, *_ = env.step(policy.decide(obs))
        frames = env.stream.dataset_index(env.slot_frames(obs.slot))
        after = env.stream.dataset_index(obs.map_frames)
        if k < 30 or before.size == 0:
            continue                      # the map fills first, as in slots_per_second
        _, inv, pos, comp, n_comp, log_det, _ = kernels.gathered_factored_scores(
            dense, before, frames[:1], PIVOT_RTOL)
        early = np.ascontiguousarray(dense[np.ix_(frames[:lag], before)], dtype=np.float64)
        t0 = time.perf_counter()
        kernels.augmented_log_taus(inv, pos, comp, n_comp, early, np.arange(lag), None,
                                   log_det, 0.0, 0.0, PIVOT_RTOL)
        kernels.gathered_factored_scores(dense, after, frames[lag:], PIVOT_RTOL)
        times.append(time.perf_counter() - t0)
    return float(np.median(times))


def adapt_ratio(dataset: CovisibilityDataset, repeats: int = 9) -> tuple[float, float]:
    """Seconds per ADAPT decision (8 uploads, 8 evictions): incremental, naive."""
    rng = np.random.default_rng(0)
    inc, naive = [], []
    for _ in range(repeats):
        start = int(rng.integers(0, dataset.n_frames - 105))
        idx = np.arange(start, start + 105)
        w = dataset.weights(idx, idx)
        np.fill_diagonal(w, 0)
        m_idx, c_idx = list(range(45)), list(range(45, 105))
        t0 = time.perf_counter()
        picks = greedy_additions(w[np.ix_(m_idx, m_idx)], w[np.ix_(c_idx, m_idx)],
                                 w[np.ix_(c_idx, c_idx)], 8)
        union = sorted(m_idx + [c_idx[i] for i in picks])
        greedy_removals(w[np.ix_(union, union)], 8)
        inc.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        naive_greedy(w, m_idx, c_idx, 8, 8)
        naive.append(time.perf_counter() - t0)
    return float(np.median(inc)), float(np.median(naive))


POLICIES = ("lff", "pu", "random", "adapt")
#: run in a tree (the baseline's or this one): slots/s per policy and rule as JSON; only
#: functions the baselines have too
_DRIVER = """
import json, sys
from bench.sim import slots_per_second
from twinslam.covisibility.dataset import load_covisibility
covis, slots, repeats, names, rules = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), \\
    sys.argv[4].split(','), sys.argv[5].split(',')
data = load_covisibility(covis)
print(json.dumps({f"{n} {r}": slots_per_second(data, n, slots, repeats, r == 'paper')[0]
                  for n in names for r in rules}))
"""


def _in_tree(root: Path, covis: str, slots: int, repeats: int, rules: tuple[str, ...]
             ) -> dict[str, float]:
    result: dict[str, float] = run_in_tree(root, _DRIVER, covis, str(slots), str(repeats),
                                           ",".join(POLICIES), ",".join(rules))
    return result


def compare(baseline: str, covis: str, slots: int, repeats: int, rounds: int,
            rules: tuple[str, ...]) -> None:
    """The baseline commit's simulator and this tree's, alternately, ``rounds`` times; the
    median slots/s of each and its ratio to the gauge taken just before."""
    def measure(r: int, label: str, root: Path) -> tuple[dict[str, float], float]:
        gauge = python_steps_per_s()
        result = _in_tree(root, covis, slots, repeats, rules)
        print(f"round {r + 1} {label}: gauge {gauge:.1f} M steps/s", flush=True)
        return result, gauge

    runs = alternately(baseline, rounds, measure)
    print(f"\n{'policy rule':<15} {'baseline ' + baseline:>22} {'current':>22}   "
          "(median slots/s, and / M gauge steps/s)")
    for key in runs["current"][0][0]:
        cells = []
        for label in ("baseline", "current"):
            rates = [res[key] for res, _ in runs[label]]
            ratios = [res[key] / g for res, g in runs[label]]
            cells.append(f"{statistics.median(rates):8.0f} ({statistics.median(ratios):6.1f})")
        print(f"{key:<15} {cells[0]:>22} {cells[1]:>22}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--covis", default=str(REAL_COVIS),
                        help="covisibility .npz, or 'room' for the geometric room model "
                             "(default: the 7-Scenes sample's, the data the experiments use)")
    parser.add_argument("--slots", type=int, default=100, help="slots per run")
    parser.add_argument("--repeats", type=int, default=5, help="runs per policy")
    parser.add_argument("--rule", choices=("both", "device", "paper"), default="both",
                        help="the rule of a lost frame the slots are scored by (default both)")
    parser.add_argument("--devices", type=int, default=100,
                        help="also a fleet of this many devices inside one keyframe budget, "
                        "per allocator; 0: none")
    add_baseline_options(parser, 3, "with --baseline: baseline/current pairs")
    args = parser.parse_args()
    rules = ("device", "paper") if args.rule == "both" else (args.rule,)
    if args.baseline:
        if args.covis == "room":
            parser.error("--baseline takes a covisibility file")
        compare(args.baseline, str(Path(args.covis).resolve()), args.slots, args.repeats,
                args.rounds, rules)
        return
    dataset = geometric_covisibility(n_frames=1000, n_points=4000) if args.covis == "room" \
        else load_covisibility(args.covis)
    print(f"machine: {platform.node()} {platform.machine()} python {platform.python_version()}; "
          f"covisibility: {dataset.source or args.covis} ({dataset.n_frames} frames)")
    print(cpu_gauge(), "(before)")
    for name in POLICIES:
        for rule in rules:
            gauge = python_steps_per_s()
            full, decide = slots_per_second(dataset, name, args.slots, args.repeats,
                                            paper_rule=rule == "paper")
            print(f"{name:<7} {rule:<7} {full:8.0f} slots/s (decide+update+reward), "
                  f"{full / gauge:6.1f} per M gauge steps/s   {decide:9.0f} decisions/s")
    floor = reward_kernel_seconds(dataset)
    gauge = python_steps_per_s()
    print(f"reward kernels alone (device's rule, LFF's maps): {floor * 1e6:.0f} µs a slot — "
          f"at most {1 / floor:.0f} slots/s, {1 / floor / gauge:.1f} per M gauge steps/s")
    inc, naive = adapt_ratio(dataset)
    print(f"ADAPT decision (V_max 45, 60 candidates, 8 up / 8 evict): incremental "
          f"{inc * 1000:.2f} ms, naive {naive * 1000:.1f} ms, ratio {naive / inc:.1f}x")
    if args.devices:      # one budget over many devices (bench.fleet has more sizes)
        for allocator in ("equal", "motion", "twin"):
            rate = fleet_device_slots_per_s(args.devices, allocator, "lff", 20, dataset)
            print(f"fleet   {args.devices} devices, LFF, {allocator:<6} {rate:8.0f} "
                  "device-slots/s")
    print(cpu_gauge(), "(after)")


if __name__ == "__main__":
    main()
