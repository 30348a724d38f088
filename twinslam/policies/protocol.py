"""The one interface every map-management policy has, and the optional capabilities a policy
declares (docs/architecture.md §13).

A policy sees a :class:`~twinslam.policies.actions.SlotObservation` and answers a
:class:`~twinslam.policies.actions.MapAction` of Theorem 1's sizes. What else a policy can do
it declares by having the method or attribute, and callers test it with ``isinstance``
against these protocols, never by probing for a name.
"""

from __future__ import annotations

from typing import Any, Protocol, runtime_checkable

from twinslam.policies.actions import MapAction, SlotObservation


class MapPolicy(Protocol):
    name: str

    def reset(self, seed: int | None = None) -> None: ...

    def decide(self, obs: SlotObservation) -> MapAction: ...


@runtime_checkable
class SlotViewer(Protocol):
    """A policy that looks at the slot's camera view before it decides: the edge's slot
    planner shows it a ``SlotView`` (``mpc`` at the edge predicts the next frames from it)."""

    def see_slot(self, view: Any) -> None: ...


@runtime_checkable
class WorldPlanner(Protocol):
    """A policy that plans in a world model: a roll-out attaches it to the
    environment before the episode (``mpc`` imagines the future there)."""

    def attach(self, env: Any) -> None: ...


@runtime_checkable
class TwinCapable(Protocol):
    """A policy that may decide on the twin's features in place of its own rate model's (the
    learned policy; ``uses_twin`` says whether this checkpoint does)."""

    @property
    def uses_twin(self) -> bool: ...


def needs_twin(policy: object) -> bool:
    """Whether ``policy`` decides on the twin's features (the edge then feeds it latents and
    keeps a fallback for when none are fresh)."""
    return isinstance(policy, TwinCapable) and bool(policy.uses_twin)
