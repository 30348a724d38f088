"""Learned-policy benchmark: wall time of a training run on this machine's cores,
and the policy's inference milliseconds per slot (state graph + ADAPT feature + rate-model
features + actor), the work ``policy:=mbrl`` adds to the edge's plan.

    python -m bench.mbrl [--slots 3000] [--rate-model regime] [--threads 2]
    python -m bench.mbrl --policy results/amm_udt_n2.pt     # inference of a trained policy only
    python -m bench.mbrl --actor paper --slots 600 --validate-every 0 --threads 1 --profile
                                                  # where a training's time goes (cProfile)
    python -m bench.mbrl --actor paper --slots 600 --validate-every 0 --threads 1 \
        --baseline COMMIT [--rounds 2]             # that commit's training beside this tree's

Targets: training ≤ 10 min on 2 cores, inference ≤ 10 ms per slot (median).
"""

from __future__ import annotations

import argparse
import cProfile
import platform
import pstats
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

from bench.baseline import add_baseline_options, alternately, run_in_tree
from bench.gauge import cpu_gauge, python_steps_per_s
from twinslam.policies.learned.policy import MbrlPolicy
from twinslam.policies.world_model import MapManagementEnv, SimConfig
from twinslam.simulator.covisibility_spec import open_covisibility
from twinslam.training.trainer import AmmTrainer, TrainConfig
from twinslam.uplink.channels import parse_channel

COVIS = Path(__file__).resolve().parents[1] / "data" / "7scenes-redkitchen-1000.covis.npz"


#: a training's wall time in a tree (the baseline's or this one), as JSON; only what the
#: baselines have too
_DRIVER = """
import json, sys, time
import torch
from twinslam.training.trainer import AmmTrainer, TrainConfig
from twinslam.simulator.covisibility_spec import open_covisibility
covis, slots, threads, actor, rate_model, channel, every = sys.argv[1:8]
torch.set_num_threads(int(threads))
trainer = AmmTrainer(TrainConfig(channel=channel, slots=int(slots), rate_model=rate_model,
                                 actor=actor, validate_every=int(every)),
                     open_covisibility(covis))
t0 = time.perf_counter()
trainer.train()
print(json.dumps({"seconds": time.perf_counter() - t0}))
"""


def compare(args: argparse.Namespace) -> None:
    """The baseline commit's training and this tree's, alternately, ``--rounds`` times (the
    same configuration and seed), with the gauge before each."""
    def measure(r: int, label: str, root: Path) -> tuple[float, float]:
        gauge = python_steps_per_s()
        out = run_in_tree(root, _DRIVER, args.covis, str(args.slots), str(args.threads),
                          args.actor, args.rate_model, args.channel, str(args.validate_every))
        ms = out["seconds"] / args.slots * 1e3
        print(f"round {r + 1} {label}: {ms:.1f} ms a slot (gauge {gauge:.1f} M steps/s)",
              flush=True)
        return ms, gauge

    runs = alternately(args.baseline, args.rounds, measure)
    print(f"\n{'':<10} {'baseline ' + args.baseline:>24} {'current':>12}")
    medians = {label: float(np.median([ms for ms, _ in rows])) for label, rows in runs.items()}
    print(f"{'ms a slot':<10} {medians['baseline']:>24.1f} {medians['current']:>12.1f}"
          f"   (median of {args.rounds}; {medians['baseline'] / medians['current']:.2f}× faster)")
    print(f"30 000 slots: {medians['baseline'] * 0.5:.1f} min → {medians['current'] * 0.5:.1f} "
          "min at these paces")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--covis", default=str(COVIS),
                        help="covisibility dataset: FILE[@START:END] or geometric[:N[:SEED]]")
    parser.add_argument("--slots", type=int, default=3000, help="real slots to train on")
    parser.add_argument("--rate-model", default="regime", help="regime, udt, lstm or markov")
    parser.add_argument("--channel", default="markov:N=2", help="uplink rate model spec")
    parser.add_argument("--threads", type=int, default=2, help="torch threads")
    parser.add_argument("--actor", default="residual", choices=["paper", "residual"],
                        help="the actor trained (default %(default)s)")
    parser.add_argument("--validate-every", type=int, default=500,
                        help="slots between validations (0: none; default %(default)s)")
    parser.add_argument("--profile", action="store_true",
                        help="also print the training's 15 largest items by own time (cProfile)")
    parser.add_argument("--policy", type=Path, help="time this checkpoint's inference; no training")
    add_baseline_options(parser, 2, "with --baseline: baseline/current pairs")
    args = parser.parse_args()
    if args.baseline:
        if args.policy or args.profile:
            parser.error("--baseline times trainings only (no --policy, no --profile)")
        file, at, window = args.covis.partition("@")
        if Path(file).exists():               # the baseline runs in its own directory
            args.covis = str(Path(file).resolve()) + at + window
        compare(args)
        return
    torch.set_num_threads(args.threads)
    dataset = open_covisibility(args.covis)
    print(f"machine: {platform.machine()} python {platform.python_version()}, torch "
          f"{torch.__version__}, {args.threads} threads; {args.rate_model}, {args.channel}")
    print(cpu_gauge(), "(before)")
    train_s = None
    if args.policy:
        policy = MbrlPolicy(args.policy)
    else:
        trainer = AmmTrainer(TrainConfig(channel=args.channel, slots=args.slots,
                                         rate_model=args.rate_model, actor=args.actor,
                                         validate_every=args.validate_every), dataset)
        profiler = cProfile.Profile() if args.profile else None
        t0 = time.perf_counter()
        if profiler:
            profiler.enable()
        trainer.train()
        if profiler:
            profiler.disable()
        train_s = time.perf_counter() - t0
        if profiler:
            pstats.Stats(profiler).sort_stats("tottime").print_stats(15)
        with tempfile.TemporaryDirectory() as tmp:
            path = Path(tmp) / "policy.pt"
            trainer.save(path)
            policy = MbrlPolicy(path)
    env = MapManagementEnv(dataset, parse_channel(args.channel, seed=0), SimConfig(slots=200))
    obs, _ = env.reset(0)
    policy.reset(0)
    infer_ms = []
    for _ in range(200):
        t1 = time.perf_counter()
        action = policy.decide(obs)
        infer_ms.append((time.perf_counter() - t1) * 1e3)
        obs, *_ = env.step(action)
    if train_s is not None:
        print(f"training: {args.slots} slots in {train_s:.0f} s ({train_s / 60:.1f} min, "
              f"{train_s / args.slots * 1e3:.0f} ms a slot)   target <= 10 min")
    print(f"inference per slot: median {np.median(infer_ms):.2f} ms, p90 "
          f"{np.percentile(infer_ms, 90):.2f} ms   target <= 10 ms")
    print(cpu_gauge(), "(after)")


if __name__ == "__main__":
    main()
