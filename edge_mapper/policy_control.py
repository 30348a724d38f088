"""Which policy decides the edge's next slot: live parameter changes and the twin's fallback.

The operator may change ``policy``, ``policy_checkpoint``, ``fallback_policy`` and
``latent_max_age`` while the edge runs (``ros2 param set``; ``vmax`` too, which the node hands
straight to its core, the one owner of V_max). A change takes effect
at the next slot; a policy that cannot be made is refused with the reason, the previous one
goes on deciding, and the same refused values are not tried again until a parameter changes.
A twin-driven learned policy comes wrapped with its fallback (:mod:`edge_mapper.twin_feed`);
a switch between the two is reported once.

Pure logic: the node hands in the live values and logs the :class:`Note` s it gets back.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, cast

from edge_mapper.planning_world import at_the_edge
from edge_mapper.twin_feed import TwinDrivenPolicy, TwinFedPolicy
from twinslam.policies.protocol import MapPolicy, needs_twin
from twinslam.policies.registry import LEARNED_PREFIX, make_policy

#: the live parameters that say which policy decides
POLICY_KEYS = ("policy", "policy_checkpoint", "fallback_policy", "latent_max_age")


@dataclass(frozen=True)
class Note:
    level: str                   #: "info" | "warning" | "error"
    text: str


def policy_refused(name: str) -> str | None:
    """Why ``name`` is not a policy the edge can run (None: it is)."""
    if name == LEARNED_PREFIX:            # its checkpoint comes from policy_checkpoint
        return None
    try:                  # made as the edge runs it: mpc's simulator-only options refused
        at_the_edge(make_policy(name))
    except ValueError as exc:
        return str(exc)
    return None


def fallback_refused(name: str) -> str | None:
    reason = policy_refused(name)
    if reason is None and name == LEARNED_PREFIX:
        reason = "the fallback must be a rule policy (lff, pu, adapt, ...)"
    return reason


def checkpoint_refused(path: str) -> str | None:
    return None if not path or Path(path).is_file() else f"{path}: no such policy checkpoint"


def policy_name(live: dict[str, Any]) -> str:
    """The registry name the live values spell: ROS style ``policy:=mbrl
    policy_checkpoint:=PATH`` is ``mbrl:PATH``."""
    name = str(live["policy"])
    if name == LEARNED_PREFIX and live["policy_checkpoint"]:
        name = f"{LEARNED_PREFIX}:{live['policy_checkpoint']}"
    return name


def make_policies(live: dict[str, Any], warm_up: Any = None
                  ) -> tuple[MapPolicy, TwinFedPolicy | None]:
    """The policy the live values name (warmed up by ``warm_up(policy)`` if given) and its
    twin feed: a twin-driven policy comes wrapped with its fallback (the wrapper is both), any
    other with no feed. ValueError when it cannot be made."""
    policy = at_the_edge(make_policy(policy_name(live)))
    if warm_up:
        warm_up(policy)
    if not needs_twin(policy):
        return policy, None
    fallback = make_policy(str(live["fallback_policy"]))
    if needs_twin(fallback):
        raise ValueError("fallback_policy must not need the twin itself")
    if warm_up:
        warm_up(fallback)
    # uses_twin: an MbrlPolicy of a twin checkpoint, which takes the twin's features
    feed = TwinFedPolicy(cast(TwinDrivenPolicy, policy), fallback, int(live["latent_max_age"]))
    return feed, feed


class PolicyControl:
    """The deciding policy as the live parameters say, slot by slot."""

    def __init__(self, live: dict[str, Any], warm_up: Any = None) -> None:
        self.warm_up = warm_up
        self.live = dict(live)
        self.policy, self.feed = make_policies(self.live, warm_up)
        self._refused: dict[str, Any] | None = None
        self._decided_by = self.policy_name

    @property
    def policy_name(self) -> str:
        return policy_name(self.live)

    def apply(self, live: dict[str, Any], slot: int) -> list[Note]:
        """Adopt the values set since the last slot; what changed (or was refused)."""
        if live == self.live or live == self._refused:
            return []
        notes = []
        changed = {k: v for k, v in live.items() if self.live[k] != v}
        adopted = dict(live)
        if changed.keys() & POLICY_KEYS:
            try:
                self.policy, self.feed = make_policies(live, self.warm_up)
            except ValueError as exc:
                notes.append(Note("error", f"slot {slot}: cannot switch to {changed} ({exc}); "
                                           f"{self.policy_name} goes on deciding"))
                self._refused = dict(live)     # not tried again until a parameter changes
                adopted.update({k: self.live[k] for k in changed if k in POLICY_KEYS})
        if adopted != self.live:
            self.live = adopted
            notes.append(Note("info", f"slot {slot}: parameters now {changed}; policy "
                                      f"{self.policy_name}"))
        return notes

    def decided(self, slot: int) -> tuple[str, list[Note]]:
        """Which policy decided ``slot`` (its plan was just made), and a note when that
        changed between the learned policy and its fallback."""
        if self.feed is None:
            self._decided_by = self.policy_name
            return self.policy_name, []
        feed = self.feed
        used = self.policy_name if feed.used == feed.name \
            else f"{feed.fallback_name} (fallback)"
        notes = []
        if used != self._decided_by:
            latent = feed.latent
            if used == self.policy_name and latent is not None:
                notes.append(Note("info", f"slot {slot}: rate latents from the twin again "
                                          f"(slot {latent.slot}, model version "
                                          f"{latent.model_version}); {feed.name} decides"))
            else:
                last = f"slot {latent.slot}" if latent is not None else "none yet"
                notes.append(Note("warning", f"slot {slot}: no rate latent from the twin "
                                             f"within {feed.max_age} slots (last: {last}); "
                                             f"deciding with the fallback policy "
                                             f"{feed.fallback_name}"))
            self._decided_by = used
        return used, notes
