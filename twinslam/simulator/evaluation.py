"""Evaluating policies over seeds: per run and per policy, mean υ (a lost frame scoring 0),
the share of lost frames and υ over the tracked frames (DESIGN.md §2, §9)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

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
        return self.tally.tracked_mean


@dataclass
class PolicyResult:
    policy: str
    runs: list[RunScore]

    @property
    def per_seed(self) -> list[float]:
        """Mean υ of each run (a lost frame scoring 0)."""
        return [r.mean_uncertainty for r in self.runs]

    @property
    def pooled(self) -> UncertaintyTally:
        total = UncertaintyTally()
        for run in self.runs:
            total = total.add(run.tally)
        return total

    @property
    def mean(self) -> float:
        return float(np.mean(self.per_seed))

    @property
    def ci95(self) -> float:
        return mean_ci95(self.per_seed)[1]

    @property
    def lost_ratio(self) -> float:
        """Share of next-slot frames, over every run, that share no map point."""
        return self.pooled.lost_share

    @property
    def mean_tracked(self) -> float:
        """Mean υ over the tracked frames of every run."""
        return self.pooled.tracked_mean


def evaluate(policies: list[str], dataset: CovisibilityDataset, channel_spec: str,
             config: SimConfig, seeds: list[int],
             rate_range: tuple[float, float] = table1.RATE_RANGE_MBPS,
             progress: Callable[[str], None] | None = None,
             make_policy: Callable[[str], MapPolicy] = make_rule_policy) -> list[PolicyResult]:
    """Each policy (by name, built with ``make_policy``) over every seed. ``reference`` is the
    clairvoyant :class:`ReferencePlanner`, started from the rule policies and every other
    policy of the list. The simulator knows only the rule policies; callers above the learning
    core pass :func:`twinslam.policy_registry.make_policy` to evaluate learned ones too."""
    if "oracle" in policies:
        raise ValueError("'oracle' is now called 'reference': it is a clairvoyant search, not a "
                         "bound (issue #18)")
    parse_channel(channel_spec, rate_range)      # a bad channel fails before the first run
    results = []
    for name in policies:
        runs: list[RunScore] = []
        label = name
        for seed in seeds:
            env = MapManagementEnv(dataset, parse_channel(channel_spec, rate_range, seed), config)
            if name == "reference":
                plan = ReferencePlanner(_reference_seeds(policies, make_policy)).plan(env, seed)
            else:
                policy = make_policy(name)
                label = policy.name
                plan = rollout(env, policy, seed)
            runs.append(RunScore(label, seed, plan.tally))
            if progress:
                r = runs[-1]
                progress(f"{label}: seed {seed} mean υ {r.mean_uncertainty:.2f}, lost "
                         f"{r.lost_share:.1%}, υ tracked {r.tracked_uncertainty:.2f}")
        results.append(PolicyResult(label, runs))
    return results


def _reference_seeds(policies: list[str], make_policy: Callable[[str], MapPolicy]
                     ) -> list[MapPolicy]:
    """The rule policies and every other evaluated policy, each once."""
    seeds = {p.name: p for p in rule_policies()}
    for name in policies:
        if name != "reference":
            policy = make_policy(name)
            seeds.setdefault(policy.name, policy)
    return list(seeds.values())
