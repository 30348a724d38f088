"""Evaluating policies over seeds: per run and per policy, mean υ (a lost frame scoring 0),
the share of lost frames and υ over the tracked frames (docs/architecture.md §2, §9)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from twinslam.covisibility.dataset import CovisibilityDataset
from twinslam.policies.plan import rollout
from twinslam.policies.protocol import MapPolicy
from twinslam.policies.reference import ReferencePlanner, rule_policies
from twinslam.policies.rules import make_rule_policy
from twinslam.policies.world_model import MapManagementEnv, SimConfig
from twinslam.reporting import mean_ci95
from twinslam.slot_protocol import table1
from twinslam.sweeps import Executor, LocalExecutor, run_tasks
from twinslam.uncertainty.map_uncertainty import UncertaintyTally
from twinslam.uplink.channels import parse_channel


@dataclass
class RunScore:
    """One run (policy × seed): υ pooled over its slots' frames."""

    policy: str
    seed: int
    tally: UncertaintyTally
    restored: int = 0           #: archived keyframes its plan brought back (downlink only)

    @property
    def mean_uncertainty(self) -> float:
        return self.tally.mean

    @property
    def lost_share(self) -> float:
        return self.tally.lost_share

    @property
    def tracked_uncertainty(self) -> float:
        return self.tally.tracked_uncertainty


class PooledScores:
    """Lost share and tracked υ of a result pooled over all its frames (a subclass says which
    frames, as ``pooled``); one place for both, so every result reports them alike."""

    @property
    def pooled(self) -> UncertaintyTally:
        raise NotImplementedError

    @property
    def lost_share(self) -> float:
        """Share of next-slot frames, over every run, that are lost (too few shared map
        points: twinslam/slot_protocol/lost_frame_rule.py)."""
        return self.pooled.lost_share

    @property
    def tracked_uncertainty(self) -> float:
        """Mean υ over the tracked frames of every run."""
        return self.pooled.tracked_uncertainty


@dataclass
class PolicyResult(PooledScores):
    policy: str
    runs: list[RunScore]

    @property
    def per_seed(self) -> list[float]:
        """Mean υ of each run (a lost frame scoring 0)."""
        return [r.mean_uncertainty for r in self.runs]

    @property
    def pooled(self) -> UncertaintyTally:
        return UncertaintyTally.of(run.tally for run in self.runs)

    @property
    def mean(self) -> float:
        return float(np.mean(self.per_seed))

    @property
    def ci95(self) -> float:
        return mean_ci95(self.per_seed)[1]

    @property
    def restored_per_run(self) -> float:
        """Archived keyframes brought back a run, on average."""
        return float(np.mean([r.restored for r in self.runs])) if self.runs else 0.0


def distinct_labels(labels: dict[str, str]) -> dict[str, str]:
    """Policy name → the label tables show. Learned policies are labelled by their kind
    ("amm-regime-real"); several checkpoints of one kind (training runs of one variant) would
    share a row title, so each of those is told apart by its checkpoint's file name."""
    shared = {label for label in labels.values() if list(labels.values()).count(label) > 1}
    return {name: f"{label} ({Path(name.partition(':')[2]).stem or name})" if label in shared
            else label for name, label in labels.items()}


@dataclass(frozen=True)
class SeedTask:
    """Every policy on one seed's episode: a sweep's task (it pickles, so a worker process or
    a Ray task can run it). Policies are built afresh from their names in the worker."""

    policies: tuple[str, ...]
    dataset: CovisibilityDataset
    channel_spec: str
    rate_range: tuple[float, float]
    config: SimConfig
    seed: int
    make_policy: Callable[[str], MapPolicy]
    reference_swaps: int


@dataclass(frozen=True)
class SeedScores:
    """What a :class:`SeedTask` sends back: each policy's tally, in the task's order."""

    seed: int
    tallies: tuple[UncertaintyTally, ...]
    restored: tuple[int, ...] = ()     #: each policy's restores, in the task's order


def score_seed(task: SeedTask, built: dict[str, MapPolicy] | None = None) -> SeedScores:
    """Roll out every policy of ``task`` on its seed's episode (``reference`` last, started
    from the others' plans). ``built``: policies already made (the in-process path reuses
    them across seeds; each rollout resets its policy to the seed, so the scores do not
    depend on which process or which order ran the seeds)."""
    if built is None:
        built = {name: task.make_policy(name) for name in task.policies if name != "reference"}
    env = MapManagementEnv(task.dataset,
                           parse_channel(task.channel_spec, task.rate_range, task.seed),
                           task.config)
    plans = {name: rollout(env, policy, task.seed) for name, policy in built.items()}
    if "reference" in task.policies:
        plans["reference"] = ReferencePlanner(
            rule_policies(), swap_evaluations=task.reference_swaps).plan(
            env, task.seed, known=list(plans.values()))
    return SeedScores(task.seed, tuple(plans[name].tally for name in task.policies),
                      tuple(plans[name].restored for name in task.policies))


def evaluate(policies: list[str], dataset: CovisibilityDataset, channel_spec: str,
             config: SimConfig, seeds: list[int],
             rate_range: tuple[float, float] = table1.RATE_RANGE_MBPS,
             progress: Callable[[str], None] | None = None,
             make_policy: Callable[[str], MapPolicy] = make_rule_policy,
             reference_swaps: int = 400,
             executor: Executor | None = None,
             scores_in_progress: bool = True) -> list[PolicyResult]:
    """Each policy (by name, built with ``make_policy``) over every seed, in the order given.
    ``reference`` is the clairvoyant :class:`ReferencePlanner`: it decides with the rule
    policies and starts from every other listed policy's plan of the same seed. The simulator
    knows only the rule policies; callers above the learning core pass
    :func:`twinslam.policies.registry.make_policy` to evaluate learned ones too.
    ``reference_swaps``: the reference's local-search budget (plan replays per episode).
    ``executor``: where the seeds run (None or one job: in this process, in order; the same
    numbers either way). ``progress`` hears a line per seed as it lands ("[i/n] seed S", its
    policies' scores too with ``scores_in_progress``, and the elapsed time and ETA)."""
    if "oracle" in policies:
        raise ValueError("'oracle' is now called 'reference': it is a clairvoyant search, not a "
                         "bound")
    parse_channel(channel_spec, rate_range)      # a bad channel fails before the first run
    built = {name: make_policy(name) for name in policies if name != "reference"}
    labels = distinct_labels({name: built[name].name if name in built else name
                              for name in policies})
    tasks = [SeedTask(tuple(policies), dataset, channel_spec, rate_range, config, seed,
                      make_policy, reference_swaps) for seed in seeds]
    executor = executor or LocalExecutor(1)
    in_process = isinstance(executor, LocalExecutor) and executor.jobs <= 1

    def label(scores: SeedScores) -> str:
        if not scores_in_progress:
            return f"seed {scores.seed}"
        return f"seed {scores.seed}: " + ", ".join(
            f"{labels[name]} {tally.mean:.2f} ({tally.lost_share:.1%} lost)"
            for name, tally in zip(policies, scores.tallies, strict=True))

    sweep = run_tasks((lambda task: score_seed(task, built)) if in_process else score_seed,
                      tasks, executor, lambda task: f"seed {task.seed}", label, progress)
    if sweep.failures:
        failure = sweep.failures[0]
        raise RuntimeError(f"{len(sweep.failures)} of {len(tasks)} seeds failed; "
                           f"{failure.task}:\n{failure.error.rstrip()}")
    scores = sweep.in_order()
    return [PolicyResult(labels[name], [RunScore(labels[name], s.seed, s.tallies[i],
                                                 s.restored[i] if s.restored else 0)
                                        for s in scores])
            for i, name in enumerate(policies)]
