"""What every model of the uplink answers: the one protocol the policy, the trainer, the twin
node and the prediction experiment use, whichever model they hold.

The paper's system needs, of whatever knows the uplink (§V–VII):

* ``predict(history)`` — p(d_{k+1}), the next slot's state distribution after the states seen
  (what ``twinslam experiment twin-predict`` scores);
* ``features(history)`` — the policy's state augmentation (the twins' [μ, log Σ], the LSTM's
  one-hot point prediction, the counts' row for the current state);
* ``sample_next(history, count, rng)`` — next states d̂_{k+1} for artificial experiences;
* ``observe(state)`` — a slot's state, learnt from: a filter (``online``: the regime twin, the
  counts) updates its posterior, and is ``reset`` at a new run; a learned model (the
  variational twin, the LSTM) keeps its weights from run to run and says when its W slots are
  up, and then ``retrain`` fits it (or, in the twin node, a background thread does).

The twins also publish a :class:`Latent` (``RateLatent`` on ``udt/rate_latent``): the
:class:`Twin` protocol adds ``latent`` and a one-line ``describe``.

numpy only: the models that need torch live in their own modules, so a filter-driven caller
never loads it.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np


@dataclass
class Latent:
    """What a twin publishes each slot (``RateLatent``)."""

    mu: np.ndarray                 #: the twin's belief about the current regime: its mean
    sigma: np.ndarray              #: its diagonal variance Σ (same size as μ)
    next_state_probs: np.ndarray   #: (N,) p(d_{k+1} | d_k)
    model_version: int


class RateModel(Protocol):
    """A model of the uplink's state sequence (see the module docstring)."""

    #: its name in :mod:`twinslam.twin.registry` (and in policy names, tables, checkpoints)
    name: str
    #: True: a filter over the current run's states (reset per run, fed every slot); False:
    #: learned weights that carry over from run to run
    online: bool

    @property
    def n_states(self) -> int: ...

    @property
    def feature_size(self) -> int:
        """Length of :meth:`features`."""
        ...

    def reset(self) -> None:
        """A new run: a filter forgets; learned weights stay."""
        ...

    def observe(self, state: int) -> bool:
        """Slot k's state; True when a retrain is due (never for a filter)."""
        ...

    def retrain(self) -> list[float]:
        """Fit to what was observed; the loss of every step (empty for a filter)."""
        ...

    def predict(self, history: Sequence[int]) -> np.ndarray:
        """p(d_{k+1}) after ``history`` (the states so far; a filter reads only its newest)."""
        ...

    def features(self, history: Sequence[int]) -> np.ndarray:
        """The policy's state augmentation after ``history``, float32, ``feature_size`` long."""
        ...

    def sample_next(self, history: Sequence[int], count: int, rng: np.random.Generator
                    ) -> np.ndarray:
        """``count`` draws of d̂_{k+1} after ``history`` (int64)."""
        ...

    def state_dict(self) -> dict[str, Any]:
        """What a policy checkpoint stores to rebuild the model (registry.load_rate_model)."""
        ...


class Twin(RateModel, Protocol):
    """A rate model the twin node can run: it publishes a latent every slot."""

    def latent(self) -> Latent:
        """μ, Σ and p(d_{k+1}) after the states observed, with the model version."""
        ...

    def describe(self) -> str:
        """What the twin is, in one line (the node's start-up log)."""
        ...


def current_state(history: Sequence[int]) -> int:
    """The newest state of ``history`` (0 before any: what every model assumes then)."""
    return int(history[-1]) if len(history) else 0


def peaked(n_states: int, state: int, mass: float) -> np.ndarray:
    """``mass`` on ``state``, the rest spread evenly: how a point guess becomes a distribution
    that gives the other states a probability above 0."""
    if n_states == 1:
        return np.ones(1)
    out = np.full(n_states, (1.0 - mass) / (n_states - 1))
    out[state] = mass
    return out


class MatrixEstimator(RateModel, Protocol):
    """A rate model whose estimate of the current interval's transition matrix can be read
    (what the twin's Figs 3–5 score against the true matrix)."""

    def transition_matrix(self) -> np.ndarray:
        """P̂, rows the current state."""
        ...


class PredictiveFilter:
    """What the counts and the naive baselines share: a filter (``online``) whose features are
    its own p(d_{k+1}) and whose artificial next states are drawn from it. A subclass says how
    it predicts (and, when it learns from the states, how it observes and resets)."""

    online = True

    def __init__(self, n_states: int) -> None:
        if n_states < 1:
            raise ValueError(f"n_states must be >= 1, got {n_states}")
        self._n = n_states

    @property
    def n_states(self) -> int:
        return self._n

    @property
    def feature_size(self) -> int:
        return self._n

    def reset(self) -> None:
        """Nothing to forget: the prediction reads only the history it is given."""

    def observe(self, state: int) -> bool:
        return False

    def retrain(self) -> list[float]:
        """Nothing to fit."""
        return []

    def predict(self, history: Sequence[int]) -> np.ndarray:
        raise NotImplementedError

    def features(self, history: Sequence[int]) -> np.ndarray:
        return self.predict(history).astype(np.float32)

    def sample_next(self, history: Sequence[int], count: int, rng: np.random.Generator
                    ) -> np.ndarray:
        return rng.choice(self._n, size=count, p=self.predict(history))

    def state_dict(self) -> dict[str, Any]:
        return {"n_states": self._n}
