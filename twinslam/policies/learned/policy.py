"""The trained AMM actor as a map-management policy (``policy:=mbrl``).

It answers the same :class:`~twinslam.policies.actions.SlotObservation` as LFF, PU and ADAPT,
in the
simulator and in the edge node alike: the observation becomes the graph state (with the rate
model's features of the rate history), the actor scores every frame, and U_k / C_k are Theorem
1's top and bottom of those scores — no exploration noise. The rate model comes from the
checkpoint; it keeps observing the rates it is shown (the Markov estimate counts them, starting
afresh each episode) but does not retrain here.
"""

from __future__ import annotations

import pickle
from pathlib import Path
from typing import Any

import numpy as np
import torch

from twinslam.policies.actions import MapAction, SlotObservation
from twinslam.policies.learned.networks import Actor
from twinslam.policies.learned.replay import collate
from twinslam.policies.learned.state import action_from_scores, build_state, context_size
from twinslam.twin.rate_model import RateModel
from twinslam.twin.registry import TWIN_MODELS, load_rate_model

CHECKPOINT_FORMAT = "twinslam-amm-policy-1"


class PolicyCheckpointError(ValueError):
    """A file that is not a trained AMM policy."""


class MbrlPolicy:
    name = "mbrl"

    def __init__(self, checkpoint: Path) -> None:
        # a checkpoint loaded to decide (an edge node, the simulator): a GCN over a few dozen
        # frames gains nothing from a second intra-op thread, whose spinning starves the
        # node's other work when several nodes share the cores (two live runs on 2 cores
        # stalled their edges' uploads for seconds)
        torch.set_num_threads(1)
        path = Path(checkpoint)
        try:
            blob = torch.load(path, map_location="cpu", weights_only=True)
        except FileNotFoundError:
            raise PolicyCheckpointError(f"{path}: no such policy checkpoint (train one with "
                                        "`twinslam train`)") from None
        except (OSError, RuntimeError, EOFError, pickle.UnpicklingError) as exc:
            raise PolicyCheckpointError(f"{path}: not a policy checkpoint ({exc})") from None
        if not isinstance(blob, dict) or blob.get("format") != CHECKPOINT_FORMAT:
            raise PolicyCheckpointError(f"{path}: not a {CHECKPOINT_FORMAT} checkpoint")
        try:
            self._adopt(blob, path)
        except (KeyError, TypeError, ValueError, RuntimeError) as exc:   # e.g. a truncated dict
            raise PolicyCheckpointError(f"{path}: an incomplete or mismatched policy "
                                        f"checkpoint ({type(exc).__name__}: {exc})") from None

    @classmethod
    def from_blob(cls, blob: dict[str, Any], origin: str = "<memory>") -> MbrlPolicy:
        """The policy of a checkpoint dictionary not written to disk (training validates
        its current actor this way)."""
        policy = cls.__new__(cls)
        policy._adopt(blob, Path(origin))
        return policy

    def _adopt(self, blob: dict[str, Any], path: Path) -> None:
        self.path = path
        self.history = int(blob["config"]["history"])
        self.n_states = int(blob["n_states"])
        self.rate_model: RateModel = load_rate_model(str(blob["rate_model"]),
                                                     blob["rate_model_state"])
        #: the model's name now (a checkpoint of an older version may say ``udt``)
        self.rate_model_name = self.rate_model.name
        #: paper (the paper's AMM) or residual (ADAPT + residual RL); older checkpoints: residual
        self.actor_variant = str(blob["config"].get("actor", "residual"))
        self.actor = Actor(context_size(self.history, self.n_states,
                                        self.rate_model.feature_size), self.actor_variant)
        self.actor.load_state_dict(blob["actor"])
        self.actor.eval()
        real_only = int(blob["config"].get("artificial_per_real", 1)) == 0
        #: as tables show it: amm-regime (the paper's AMM on the regime twin), mbrl-variational
        #: (ADAPT + residual RL on the variational twin); -real
        #: for a policy trained without artificial tuples
        kind = "amm" if self.actor_variant == "paper" else "mbrl"
        self.name = f"{kind}-{self.rate_model_name}{'-real' if real_only else ''}"
        self._seen = 0

    def reset(self, seed: int | None = None) -> None:
        self.rate_model.reset()        # a filter (regime, counts) starts afresh each run
        self._seen = 0

    @property
    def uses_twin(self) -> bool:
        """Driven by a user digital twin (regime or variational): on the edge its features can come
        from the twin node's ``/udt/rate_latent`` (the node running the same model) instead
        of the checkpoint's copy of the twin."""
        return self.rate_model_name in TWIN_MODELS

    @property
    def feature_size(self) -> int:
        return self.rate_model.feature_size

    @torch.no_grad()
    def decide(self, obs: SlotObservation, rate_features: np.ndarray | None = None
               ) -> MapAction:
        """U_k and C_k; ``rate_features`` (the rate model's ``features``, e.g. the twin node's
        [μ, log Σ]) replace what the checkpoint's own rate model would compute."""
        if obs.n_states != self.n_states:
            raise ValueError(f"policy {self.path} was trained for {self.n_states} rate states,"
                             f" the channel has {obs.n_states}")
        if self.rate_model.online:
            unseen = obs.slot + 1 - self._seen
            for state in obs.rate_history[-unseen:] if unseen > 0 else []:
                self.rate_model.observe(state)       # the slots not counted yet
            self._seen = obs.slot + 1
        if rate_features is None:
            rate_features = self.rate_model.features(obs.rate_history)
        elif rate_features.shape != (self.feature_size,):
            raise ValueError(f"policy {self.path} takes {self.feature_size} rate features, got "
                             f"{rate_features.shape}")
        graph = build_state(obs, rate_features, self.history,
                            adapt_features=self.actor_variant == "residual")
        batch = collate([graph])
        scores = self.actor(batch.x, batch.prop, batch.mask, batch.context)[0].numpy()
        return action_from_scores(graph, scores.astype(np.float64))[0]
