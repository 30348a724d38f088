"""``twinslam train``: the learned (MBRL) map-management policy trained in the simulator, one
run or several (``--runs``) on any executor."""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from twinslam.cli.arguments import (
    add_executor_arguments,
    add_setting_arguments,
    covisibility,
    open_executor,
)
from twinslam.cli.console import Subparsers, error, failed_tasks, warn_aliases
from twinslam.covisibility.dataset import CovisibilityError
from twinslam.twin.registry import ALIASES, POLICY_RATE_MODELS, canonical
from twinslam.uplink.channels import ChannelError


def run(args: argparse.Namespace) -> int:
    # imported here: the trainer loads torch, which the other commands never need
    from twinslam.experiments.training import (
        TrainOutcome,
        snapshots_path,
        train_one,
        train_tasks,
    )
    from twinslam.simulator.covisibility_spec import absolute_spec
    from twinslam.sweeps import run_tasks
    from twinslam.training.trainer import AmmTrainer, TrainConfig

    t0 = time.monotonic()
    warn_aliases([args.rate_model], ALIASES)
    try:
        if args.runs < 1:
            raise ValueError(f"--runs must be >= 1, got {args.runs}")
        dataset = covisibility(args.covis)
        config = TrainConfig(channel=args.channel, rate_range=args.rate_range,
                             vmax=args.vmax, slots=args.slots, episode_slots=args.episode_slots,
                             seed=args.seed, rate_model=canonical(args.rate_model),
                             actor=args.actor,
                             real_fraction=args.real_fraction,
                             artificial_per_real=args.artificial,
                             validate_every=args.validate_every)
        if args.snapshots and not args.validate_every:
            raise ValueError("--snapshots keeps the validated actors: it needs "
                             "--validate-every > 0")
        AmmTrainer(config, dataset)          # a bad setting fails here, before any worker
        threads_per_run(args)
        executor = open_executor(args)
    except (ChannelError, CovisibilityError, ValueError, RuntimeError) as exc:
        return error(exc)
    seeds = list(range(args.seed, args.seed + args.runs))
    tasks = train_tasks(config, absolute_spec(args.covis), Path(args.output), seeds,
                        threads_per_run(args), verbose=args.runs == 1 or args.verbose,
                        snapshots=args.snapshots)
    print(f"training on {dataset.n_frames} frames ({dataset.source or args.covis}); channel "
          f"{args.channel}; V_max {args.vmax}; actor {args.actor}; rate model "
          f"{canonical(args.rate_model)}; I/|Ξ| "
          f"{config.real_count}/{config.batch_size}, J {config.artificial_per_real}; "
          f"{args.slots} slots; {len(seeds)} run(s), seed(s) {seeds[0]}..{seeds[-1]}",
          flush=True)

    def label(out: TrainOutcome) -> str:
        return (f"seed {out.seed}: {out.checkpoint} kept the actor of slot {out.kept_slot} "
                f"(validation υ {out.best_validation:.1f}, {out.seconds:.0f} s)")

    failures_file = Path(args.output).with_name(Path(args.output).stem + "_failures.txt")
    with executor:
        sweep = run_tasks(train_one, tasks, executor, lambda t: f"training seed {t.config.seed}",
                          label, lambda line: print(line, flush=True), failures_file)
    for out in sweep.in_order():
        print(f"wrote {out.checkpoint} (use it as --policy mbrl:{out.checkpoint}) and the "
              f"training log {out.log}"
              + (f"; snapshots {snapshots_path(out.checkpoint)}" if args.snapshots else ""))
    print(f"{len(sweep.results)} of {len(tasks)} run(s) trained "
          f"({time.monotonic() - t0:.0f} s)")
    return failed_tasks(sweep.failures, "training run(s)", str(failures_file))


def threads_per_run(args: argparse.Namespace) -> int:
    """torch threads each run gets: ``--threads``, else 2 for runs in this process and 1 in
    workers (local ``--jobs`` > 1 or Ray), where the runs already share the cores — two
    threads each there oversubscribe them, and torch's spinning threads then ran a 2-core
    machine's two trainings ~5× slower (measured: 280 vs ~56 ms a slot)."""
    if args.threads is not None:
        if args.threads < 1:
            raise ValueError(f"--threads must be >= 1, got {args.threads}")
        return int(args.threads)
    in_workers = args.executor == "ray" or (args.jobs or 1) > 1
    return 1 if in_workers else 2


def register(sub: Subparsers) -> None:
    train = sub.add_parser("train", help="train the learned (MBRL) map-management policy",
                           description="Actor-critic on the map graph (paper §VI), the state "
                           "augmented by a rate model; checkpoints are validated on seeds "
                           "training never plays and the best validation is kept. Writes the "
                           "checkpoint and a CSV training log beside it; --runs R trains R "
                           "seeds (FILE_s<seed>.pt each) on the chosen executor.")
    add_setting_arguments(train)
    train.add_argument("--slots", type=int, default=3000, help="real slots to train on")
    train.add_argument("--episode-slots", type=int, default=200, help="slots per episode")
    train.add_argument("--rate-model", default="regime",
                       choices=[*POLICY_RATE_MODELS, *ALIASES],
                       help="what augments the state and generates artificial experiences: "
                       "regime (the Bayesian regime twin's posterior; the best next-state "
                       "predictor measured, `experiment twin-predict`), variational (the "
                       "twin's latent, paper §V), lstm (a point predictor), markov "
                       "(transition counts)")
    train.add_argument("--actor", default="paper", choices=["paper", "residual"],
                       help="paper: the paper's AMM (the GCN's score per frame, no ADAPT "
                       "prior, no ADAPT features; default: under the device's rule it learns "
                       "LFF's level with fewer lost frames); residual: ADAPT + residual RL "
                       "(ADAPT's decision as prior and node features, plus a learned "
                       "correction; it starts at ADAPT, which loses half the frames under "
                       "the device's rule, and stayed worse than LFF to 12 000 slots — "
                       "docs/results/learning.md)")
    train.add_argument("--real-fraction", type=float, default=0.5,
                       help="I/|Ξ|: share of real tuples in each batch, in (0, 1], when "
                       "--artificial > 0")
    train.add_argument("--artificial", type=int, default=0,
                       help="J: artificial tuples per real one; 0 (default): real experiences "
                       "only — the blended replay helped at none of 300, 1000, 3000 real slots "
                       "(docs/results/twin.md); the paper's configuration is "
                       "--artificial 2 --real-fraction 0.5")
    train.add_argument("--seed", type=int, default=0,
                       help="seed of the channel and the networks (the first run's, with --runs)")
    train.add_argument("--runs", type=int, default=1,
                       help="training runs, seeds SEED..SEED+RUNS-1; more than one writes "
                       "FILE_s<seed>.pt and .csv per run; default %(default)s")
    train.add_argument("--validate-every", type=int, default=500, metavar="SLOTS",
                       help="slots between validations on the training split's validation "
                       "seeds (the best is kept; 0: never, keep the last) (default "
                       "%(default)s)")
    train.add_argument("--snapshots", action="store_true",
                       help="also write every validated actor to FILE.snapshots.pt: what "
                       "`twinslam experiment learning-curve` evaluates on held-out data")
    train.add_argument("--threads", type=int, default=None,
                       help="torch CPU threads per run (default: 2 in this process; 1 a run "
                       "with --jobs > 1 or --executor ray, where the runs share the cores)")
    train.add_argument("-v", "--verbose", action="store_true",
                       help="with --runs > 1: every run's progress lines too (prefixed by its "
                       "seed)")
    add_executor_arguments(train, "training run")
    train.add_argument("-o", "--output", default="results/amm_policy.pt", metavar="FILE",
                       help="checkpoint to write (then --policy mbrl:FILE)")
    train.set_defaults(func=run)
