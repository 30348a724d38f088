"""Online next-state prediction: the one test every rate model can take on real data.

A transition-matrix error (Figs 3–5) needs the true matrix, which only a synthetic chain has.
What a rate model is for — telling the policy what the uplink does next — can be scored on any
state sequence: before slot k + 1 each model gives p(d_{k+1}); the state that comes is scored
by its log-likelihood log p(d_{k+1}) (a proper score: only the true distribution maximises its
expectation) and by the Brier score Σ_j (p_j − [j = d_{k+1}])²; then every model observes it
(and a learned one retrains when its W slots are up).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from twinslam.twin.rate_model import RateModel

#: a probability below this is scored as this (a point predictor's 0 would be −∞)
PROBABILITY_FLOOR = 1e-12


@dataclass
class PredictionScore:
    """One model's online scores over a sequence: sums, so runs pool exactly."""

    log_likelihood: float = 0.0      #: Σ log p(d_{k+1}), nats
    brier: float = 0.0               #: Σ Brier
    slots: int = 0                   #: predictions scored

    def add(self, probs: np.ndarray, state: int) -> None:
        self.log_likelihood += math.log(max(float(probs[state]), PROBABILITY_FLOOR))
        target = np.zeros_like(probs)
        target[state] = 1.0
        self.brier += float(((probs - target) ** 2).sum())
        self.slots += 1

    @property
    def mean_log_likelihood(self) -> float:
        return self.log_likelihood / self.slots if self.slots else math.nan

    @property
    def mean_brier(self) -> float:
        return self.brier / self.slots if self.slots else math.nan


def score_online(states: Sequence[int], models: Sequence[RateModel]
                 ) -> dict[str, PredictionScore]:
    """Predict, score, observe — slot by slot, every model on the same states. The first
    state is only observed (there is no current state to predict from before it)."""
    scores = {m.name: PredictionScore() for m in models}
    history: list[int] = []
    for k, state in enumerate(states):
        s = int(state)
        if k > 0:
            for m in models:
                probs = np.asarray(m.predict(history), dtype=np.float64)
                if probs.shape != (probs.size,) or not np.isclose(probs.sum(), 1.0, atol=1e-4):
                    raise ValueError(f"{m.name}: prediction {probs} is not a distribution")
                scores[m.name].add(probs, s)
        for m in models:
            if m.observe(s):
                m.retrain()
        history.append(s)
    return scores
