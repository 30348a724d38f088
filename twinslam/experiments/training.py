"""Several training runs of the learned policy as one sweep (``twinslam train --runs R``): one
task per training seed, each writing its checkpoint and training log, on any executor."""

from __future__ import annotations

import time
from dataclasses import dataclass, replace
from pathlib import Path

import torch

from twinslam.simulator.covisibility_spec import cached_covisibility
from twinslam.training.trainer import AmmTrainer, TrainConfig


@dataclass(frozen=True)
class TrainTask:
    """One training run: its config (seed included), the covisibility spec, where its
    checkpoint goes, torch threads, and whether to print its progress lines."""

    config: TrainConfig
    covis: str
    output: Path
    threads: int = 1
    verbose: bool = False
    snapshots: bool = False        #: also write every validated actor (a learning curve's)


@dataclass(frozen=True)
class TrainOutcome:
    """What a run left: its checkpoint and log, the kept actor's validation υ and the slot it
    was kept at (0: the untrained actor won), and the run's wall time."""

    seed: int
    checkpoint: Path
    log: Path
    best_validation: float
    kept_slot: int
    seconds: float


def run_outputs(output: Path, seeds: list[int]) -> list[Path]:
    """The checkpoint of each seed: ``output`` itself for one run, else ``stem_s{seed}``."""
    if len(seeds) == 1:
        return [output]
    return [output.with_name(f"{output.stem}_s{seed}{output.suffix}") for seed in seeds]


def snapshots_path(checkpoint: Path) -> Path:
    """Where a run's snapshots go: ``FILE.snapshots.pt`` beside ``FILE.pt``."""
    return checkpoint.with_suffix(".snapshots.pt")


def train_tasks(config: TrainConfig, covis: str, output: Path, seeds: list[int],
                threads: int, verbose: bool, snapshots: bool = False) -> list[TrainTask]:
    return [TrainTask(replace(config, seed=seed), covis, path, threads, verbose, snapshots)
            for seed, path in zip(seeds, run_outputs(output, seeds), strict=True)]


def train_one(task: TrainTask) -> TrainOutcome:
    """Train, save the kept checkpoint and the CSV log beside it."""
    started = time.monotonic()
    torch.set_num_threads(task.threads)
    seed = task.config.seed
    task.output.parent.mkdir(parents=True, exist_ok=True)

    def save(trainer: AmmTrainer) -> None:
        """What there is so far (after every validation, and at the end): a run stopped
        half-way keeps its best actor and its snapshots."""
        trainer.save(task.output)
        if task.snapshots:
            trainer.save_snapshots(snapshots_path(task.output))

    trainer = AmmTrainer(task.config, cached_covisibility(task.covis),
                         (lambda line: print(f"[seed {seed}] {line}", flush=True))
                         if task.verbose else None, snapshots=task.snapshots,
                         on_validation=save)
    log = trainer.train()
    save(trainer)
    log_path = task.output.with_suffix(".csv")
    log.write_csv(log_path)
    kept = min(trainer.validations, key=lambda v: v[1])[0] if trainer.validations else -1
    return TrainOutcome(seed, task.output, log_path, trainer.best_validation, kept,
                        time.monotonic() - started)
