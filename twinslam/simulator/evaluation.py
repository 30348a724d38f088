"""Evaluating policies over seeds: per run and per policy, mean υ (a lost frame scoring 0),
the share of lost frames and υ over the tracked frames (DESIGN.md §2, §9)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from twinslam.common import table1
from twinslam.common.reporting import mean_ci95
from twinslam.map_management.policies import MapPolicy, make_rule_policy
from twinslam.simulator.covisibility import CovisibilityDataset
from twinslam.simulator.env import MapManagementEnv, SimConfig
from twinslam.simulator.plan import rollout
from twinslam.simulator.reference import ReferencePlanner, rule_policies
from twinslam.uncertainty.map_uncertainty import UncertaintyTally
from twinslam.uplink.channels import parse_channel


@dataclass
class RunScore:
    """One run (policy × seed): υ pooled over its slots' frames."""

    policy: str
    seed: int
    tally: UncertaintyTally

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
        points: twinslam/common/tracking_rule.py)."""
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


def distinct_labels(labels: dict[str, str]) -> dict[str, str]:
    """Policy name → the label tables show. Learned policies are labelled by their kind
    ("amm-regime-real"); several checkpoints of one kind (training runs of one variant) would
    share a row title, so each of those is told apart by its checkpoint's file name."""
    shared = {label for label in labels.values() if list(labels.values()).count(label) > 1}
    return {name: f"{label} ({Path(name.partition(':')[2]).stem or name})" if label in shared
            else label for name, label in labels.items()}


def evaluate(policies: list[str], dataset: CovisibilityDataset, channel_spec: str,
             config: SimConfig, seeds: list[int],
             rate_range: tuple[float, float] = table1.RATE_RANGE_MBPS,
             progress: Callable[[str], None] | None = None,
             make_policy: Callable[[str], MapPolicy] = make_rule_policy,
             reference_swaps: int = 400) -> list[PolicyResult]:
    """Each policy (by name, built with ``make_policy``) over every seed, in the order given.
    ``reference`` is the clairvoyant :class:`ReferencePlanner`: it decides with the rule
    policies and starts from every other listed policy's plan of the same seed. The simulator
    knows only the rule policies; callers above the learning core pass
    :func:`twinslam.policy_registry.make_policy` to evaluate learned ones too.
    ``reference_swaps``: the reference's local-search budget (plan replays per episode)."""
    if "oracle" in policies:
        raise ValueError("'oracle' is now called 'reference': it is a clairvoyant search, not a "
                         "bound (issue #18)")
    parse_channel(channel_spec, rate_range)      # a bad channel fails before the first run
    built = {name: make_policy(name) for name in policies if name != "reference"}
    runs: dict[str, list[RunScore]] = {name: [] for name in policies}
    labels = distinct_labels({name: built[name].name if name in built else name
                              for name in policies})
    for seed in seeds:
        env = MapManagementEnv(dataset, parse_channel(channel_spec, rate_range, seed), config)
        plans = {name: rollout(env, policy, seed) for name, policy in built.items()}
        if "reference" in policies:
            plans["reference"] = ReferencePlanner(
                rule_policies(), swap_evaluations=reference_swaps).plan(
                env, seed, known=list(plans.values()))
        for name in policies:
            run = RunScore(labels[name], seed, plans[name].tally)
            runs[name].append(run)
            if progress:
                progress(f"{run.policy}: seed {seed} mean υ {run.mean_uncertainty:.2f}, lost "
                         f"{run.lost_share:.1%}, υ tracked {run.tracked_uncertainty:.2f}")
    return [PolicyResult(labels[name], runs[name]) for name in policies]
