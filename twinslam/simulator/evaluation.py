"""Evaluating policies over seeds: mean υ per policy with a 95 % confidence interval."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from twinslam.common import table1
from twinslam.common.reporting import mean_ci95
from twinslam.map_management.policies import MapPolicy, make_rule_policy
from twinslam.simulator.covisibility import CovisibilityDataset
from twinslam.simulator.env import MapManagementEnv, SimConfig
from twinslam.simulator.oracle import ClairvoyantOracle, Plan, rollout
from twinslam.uplink.channels import parse_channel


@dataclass
class PolicyResult:
    policy: str
    per_seed: list[float]            #: mean penalised υ of each seed's episode
    lost_ratio: float                #: share of next-slot frames that would lose tracking
    mean_tracked: float              #: mean υ over tracked frames only

    @property
    def mean(self) -> float:
        return float(np.mean(self.per_seed))

    @property
    def ci95(self) -> float:
        return mean_ci95(self.per_seed)[1]


def _episode_stats(plan: Plan) -> tuple[float, float, float]:
    """Mean υ (penalised), lost share and tracked-only mean of an episode's slots."""
    tracked = [s.mean_tracked for s in plan.slots if not math.isnan(s.mean_tracked)]
    return float(np.mean(plan.objectives)), float(np.mean([s.lost_ratio for s in plan.slots])), \
        float(np.mean(tracked)) if tracked else math.nan


def evaluate(policies: list[str], dataset: CovisibilityDataset, channel_spec: str,
             config: SimConfig, seeds: list[int],
             rate_range: tuple[float, float] = table1.RATE_RANGE_MBPS,
             progress: Callable[[str], None] | None = None,
             make_policy: Callable[[str], MapPolicy] = make_rule_policy) -> list[PolicyResult]:
    """Each policy (by name, built with ``make_policy``; ``oracle`` is the clairvoyant plan)
    over every seed. The simulator knows only the rule policies; callers above the learning
    core pass :func:`twinslam.policy_registry.make_policy` to evaluate learned ones too."""
    results = []
    for name in policies:
        per_seed, lost, tracked = [], [], []
        label = name
        for seed in seeds:
            env = MapManagementEnv(dataset, parse_channel(channel_spec, rate_range, seed), config)
            if name == "oracle":
                plan = ClairvoyantOracle().plan(env, seed)
            else:
                policy = make_policy(name)
                label = policy.name
                plan = rollout(env, policy, seed)
            mean_obj, lost_share, tracked_mean = _episode_stats(plan)
            per_seed.append(mean_obj)
            lost.append(lost_share)
            tracked.append(tracked_mean)
            if progress:
                progress(f"{label}: seed {seed} mean υ {mean_obj:.2f}")
        results.append(PolicyResult(label, per_seed, float(np.mean(lost)),
                                    float(np.nanmean(tracked)) if not all(map(math.isnan, tracked))
                                    else math.nan))
    return results
