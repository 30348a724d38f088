"""Every map-management policy by name, the learned one included: what nodes and the CLI take.

The rule-based policies (:mod:`twinslam.policies.rules`) need numpy; the learned AMM
policy needs torch and its checkpoint. This registry sits above both, at the level of the
nodes and the command line, and imports the learned policy only when one is asked for: an edge
on ``policy:=lff`` never loads torch (tests/test_layers.py), and the libraries below never
import the learning core.
"""

from __future__ import annotations

from pathlib import Path

from twinslam.policies.delayed import DELAY_PREFIX, DelayedPolicy, parse_delay
from twinslam.policies.protocol import MapPolicy
from twinslam.policies.restoring import RESTORE_PREFIX, RestoringPolicy
from twinslam.policies.rules import POLICIES, make_rule_policy

LEARNED_PREFIX = "mbrl"          #: ``mbrl:CHECKPOINT`` names a policy `twinslam train` wrote
MPC = "mpc"                      #: ``mpc[:H=3/S=4/...]``: the causal planner
#: what a policy name starts with: a rule, a learned checkpoint, the planner or a delay
POLICY_KINDS = frozenset({*POLICIES, LEARNED_PREFIX, MPC, DELAY_PREFIX, RESTORE_PREFIX})


def make_policy(name: str) -> MapPolicy:
    """A policy by name: ``lff``, ``pu``, ``adapt``, ``random``, ``mbrl:PATH`` for the
    learned policy of the checkpoint at PATH, or ``mpc[:OPTIONS]`` for the causal planner
    (:mod:`twinslam.policies.mpc`; the simulator's world model in ``twinslam sim``, a world
    built from the live map at the edge), or ``delay:SECONDS:POLICY`` for a policy's decisions
    handed back late (a control for the cost of deciding slowly), or ``restore:POLICY`` for a
    policy that also brings archived keyframes back where the device is (the simulator with
    an archive; the live edge restores by its ``restore_keyframes`` parameter instead). Unknown
    names raise ValueError listing the choices."""
    kind, _, path = name.partition(":")
    if kind == RESTORE_PREFIX:
        if not path or path.partition(":")[0] == RESTORE_PREFIX:
            raise ValueError(f"policy {name!r}: use restore:POLICY, e.g. restore:lff")
        return RestoringPolicy(make_policy(path))
    if kind == DELAY_PREFIX:
        seconds, inner = parse_delay(name)
        if inner.partition(":")[0] in (LEARNED_PREFIX, DELAY_PREFIX):
            raise ValueError(f"policy {name!r}: a delay wraps a rule policy or mpc")
        return DelayedPolicy(make_policy(inner), seconds)
    if kind == LEARNED_PREFIX:
        if not path:
            raise ValueError("policy 'mbrl' needs its checkpoint: mbrl:PATH (from "
                             "`twinslam train`)")
        from twinslam.policies.learned.policy import MbrlPolicy  # torch loads only for this policy
        return MbrlPolicy(Path(path))
    if kind == MPC:
        from twinslam.policies.mpc import MpcPlanner, parse_mpc
        config = parse_mpc(name)
        return MpcPlanner(config, learned_rates=_variational_twin
                          if config.rates == "variational" else None)
    if name not in POLICIES:
        raise ValueError(f"unknown policy {name!r}; choose from {sorted(POLICIES)}, "
                         "mbrl:CHECKPOINT, mpc[:H=../S=..], delay:SECONDS:POLICY, "
                         "restore:POLICY (or, in the simulator, 'reference')")
    return make_rule_policy(name)


def _variational_twin(n_states: int, seed: int, retrain_every: int) -> object:
    """The variational twin for ``mpc:rates=variational``, fresh each episode (seeded by it)
    and retrained every ``retrain_every`` slots on the states it has seen (torch loads here)."""
    from twinslam.twin.registry import RateModelSettings, make_rate_model
    return make_rate_model("variational", RateModelSettings(
        n_states=n_states, retrain_every=retrain_every, seed=seed))
