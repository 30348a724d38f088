"""A twin-driven policy on the edge, fed by the twin node, with a declared fallback.

In the paper's system the user digital twin runs beside the edge and hands the policy its
latent features every slot (§V, Fig. 2). On the edge that is ``/udt/rate_latent``: the learned
policy (``policy:=mbrl`` with a twin checkpoint) decides slot k with the twin node's [μ, log Σ]
when a latent at most ``max_age`` slots old has arrived. When none has — the twin host is down,
not started yet, or cut off — the slot is decided by the fallback policy the operator declared
(``fallback_policy:=adapt``), and the node says so; when latents flow again, the learned policy
takes over again. Pure logic: the node offers latents and reads which policy decided.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np

from twinslam.policies.actions import MapAction, SlotObservation
from twinslam.policies.protocol import MapPolicy
from twinslam.twin.latent import latent_features


@dataclass(frozen=True)
class ReceivedFeatures:
    """The twin node's latent as the edge keeps it: already the policy's features (the
    :class:`~twinslam.twin.rate_model.Latent` it was, on the twin's side)."""

    slot: int                      #: the slot whose throughput the twin had last seen
    features: np.ndarray           #: [μ, log Σ]
    model_version: int


class TwinDrivenPolicy(Protocol):
    """A learned policy that can take the twin's features in place of its own rate model's
    (``MbrlPolicy`` of a twin checkpoint)."""

    name: str
    feature_size: int

    def reset(self, seed: int | None = None) -> None: ...

    def decide(self, obs: SlotObservation, rate_features: np.ndarray | None = None
               ) -> MapAction: ...


class TwinFedPolicy:
    """``decide`` runs the learned policy on a fresh latent, else the fallback."""

    def __init__(self, learned: TwinDrivenPolicy, fallback: MapPolicy, max_age: int = 2
                 ) -> None:
        if max_age < 0:
            raise ValueError(f"latent max age must be >= 0 slots, got {max_age}")
        self.learned, self.fallback, self.max_age = learned, fallback, max_age
        self.name = learned.name
        self.fallback_name = fallback.name
        self.latent: ReceivedFeatures | None = None
        self.used = self.name              #: which policy decided the last slot

    def offer(self, slot: int, mu: np.ndarray, sigma: np.ndarray, model_version: int) -> None:
        """A latent from the twin node; refused (ValueError) if the learned policy cannot
        take it, e.g. a twin of another latent size."""
        features = latent_features(mu, sigma)
        size = self.learned.feature_size
        if features.size != size:
            raise ValueError(f"a latent of {features.size // 2} dimensions; the policy was "
                             f"trained on a twin of {size // 2}")
        if self.latent is None or slot >= self.latent.slot:
            self.latent = ReceivedFeatures(slot, features, model_version)

    def fresh(self, slot: int) -> bool:
        return self.latent is not None and slot - self.latent.slot <= self.max_age

    def decide(self, obs: SlotObservation) -> MapAction:
        if self.fresh(obs.slot):
            assert self.latent is not None
            self.used = self.name
            return self.learned.decide(obs, rate_features=self.latent.features)
        self.used = self.fallback_name
        return self.fallback.decide(obs)

    def reset(self, seed: int | None = None) -> None:
        self.learned.reset(seed)
        self.fallback.reset(seed)
