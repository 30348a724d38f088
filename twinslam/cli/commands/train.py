"""``twinslam train``: the learned (MBRL) map-management policy trained in the simulator."""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from twinslam.cli.arguments import add_setting_arguments, covisibility
from twinslam.cli.console import Subparsers, elapsed_progress, error, warn_aliases
from twinslam.simulator.covisibility import CovisibilityError
from twinslam.twin.registry import ALIASES, POLICY_RATE_MODELS, canonical
from twinslam.uplink.channels import ChannelError


def run(args: argparse.Namespace) -> int:
    # imported here: the trainer loads torch, which the other commands never need
    import torch

    from twinslam.mbrl.trainer import AmmTrainer, TrainConfig

    t0 = time.monotonic()
    warn_aliases([args.rate_model], ALIASES)
    try:
        dataset = covisibility(args.covis)
        config = TrainConfig(channel=args.channel, rate_range=args.rate_range,
                             vmax=args.vmax, slots=args.slots, episode_slots=args.episode_slots,
                             seed=args.seed, rate_model=canonical(args.rate_model),
                             actor=args.actor,
                             real_fraction=args.real_fraction,
                             artificial_per_real=args.artificial)
        torch.set_num_threads(args.threads)
        trainer = AmmTrainer(config, dataset, elapsed_progress())
    except (ChannelError, CovisibilityError, ValueError) as exc:
        return error(exc)
    print(f"training on {dataset.n_frames} frames ({dataset.source or args.covis}); channel "
          f"{args.channel}; V_max {args.vmax}; actor {args.actor}; rate model "
          f"{canonical(args.rate_model)}; I/|Ξ| "
          f"{config.real_count}/{config.batch_size}, J {config.artificial_per_real}; "
          f"{args.slots} slots", flush=True)
    log = trainer.train()
    out = Path(args.output)
    out.parent.mkdir(parents=True, exist_ok=True)
    trainer.save(out)
    log_path = out.with_suffix(".csv")
    log.write_csv(log_path)
    print(f"wrote {out} (use it as --policy mbrl:{out}) and the training log {log_path} "
          f"({time.monotonic() - t0:.0f} s)")
    return 0


def register(sub: Subparsers) -> None:
    train = sub.add_parser("train", help="train the learned (MBRL) map-management policy",
                           description="Actor-critic on the map graph (paper §VI), the state "
                           "augmented by a rate model; checkpoints are validated on seeds "
                           "training never plays and the best validation is kept. Writes the "
                           "checkpoint and a CSV training log beside it.")
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
    train.add_argument("--actor", default="residual", choices=["paper", "residual"],
                       help="paper: the paper's AMM (the GCN's score per frame, no ADAPT "
                       "prior, no ADAPT features); residual: ADAPT + residual RL (ADAPT's "
                       "decision as prior and node features, plus a learned correction)")
    train.add_argument("--real-fraction", type=float, default=0.5,
                       help="I/|Ξ|: share of real tuples in each batch, in (0, 1], when "
                       "--artificial > 0")
    train.add_argument("--artificial", type=int, default=0,
                       help="J: artificial tuples per real one; 0 (default): real experiences "
                       "only — the blended replay helped at none of 300, 1000, 3000 real slots "
                       "(docs/results.md, issue #20); the paper's configuration is "
                       "--artificial 2 --real-fraction 0.5")
    train.add_argument("--seed", type=int, default=0, help="seed of the channel and the networks")
    train.add_argument("--threads", type=int, default=2, help="torch CPU threads")
    train.add_argument("-o", "--output", default="results/amm_policy.pt", metavar="FILE",
                       help="checkpoint to write (then --policy mbrl:FILE)")
    train.set_defaults(func=run)
