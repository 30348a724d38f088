"""Transition counting: the paper's "Markov model" estimator (§VII-A) as a rate model.

P̂[i, j] = (n_ij + α) / (n_i + Nα) over the whole history or the last ``window`` transitions:
α = 0 is the maximum-likelihood estimate the paper compares with (a state never left yet has a
uniform row), α = ½ the Krichevsky–Trofimov estimate the prediction experiment scores (a
maximum-likelihood 0 would be −∞ nats). The counts are kept up to date as states arrive (a
transition leaving the window is taken off again), so a query costs O(N²) however long the
history — the learned policy asks once per slot over 10⁴ slots.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from twinslam.twin.rate_model import PredictiveFilter, current_state


class MarkovCounts(PredictiveFilter):
    """A filter (``online``): counts over the current run, reset per run. Features: the
    estimated row of the current state; artificial next states drawn from it."""

    def __init__(self, n_states: int, window: int | None = None, pseudo_count: float = 0.0,
                 name: str | None = None) -> None:
        super().__init__(n_states)
        if window is not None and window < 1:
            raise ValueError("window must be >= 1 transition")
        if pseudo_count < 0:
            raise ValueError(f"pseudo_count must be >= 0, got {pseudo_count}")
        self.window, self.pseudo_count = window, pseudo_count
        self.name = name or ("markov" if window is None else "markov-window")
        self.counts = np.zeros((n_states, n_states))
        self._recent: list[int] = []        #: the window's states (the last one only if whole)

    def reset(self) -> None:
        """A new run: the counts start afresh."""
        self.counts = np.zeros((self._n, self._n))
        self._recent = []

    def observe(self, state: int) -> bool:
        s = int(state)
        if not 0 <= s < self._n:
            raise ValueError(f"state {s} outside [0, {self._n})")
        if self._recent:
            self.counts[self._recent[-1], s] += 1.0
        self._recent.append(s)
        keep = 1 if self.window is None else self.window + 1
        while len(self._recent) > keep:
            if self.window is not None:
                self.counts[self._recent[0], self._recent[1]] -= 1.0
            del self._recent[0]
        return False

    def transition_matrix(self) -> np.ndarray:
        """P̂ (rows: current state); a row never left yet (and α = 0) is uniform."""
        smoothed = self.counts + self.pseudo_count
        rows = smoothed.sum(axis=1, keepdims=True)
        return np.where(rows > 0, smoothed / np.where(rows > 0, rows, 1.0), 1.0 / self._n)

    def predict(self, history: Sequence[int]) -> np.ndarray:
        return np.asarray(self.transition_matrix()[current_state(history)])

    def state_dict(self) -> dict[str, Any]:
        return {**super().state_dict(), "counts": self.counts.tolist(), "window": self.window,
                "pseudo_count": self.pseudo_count}

    @classmethod
    def from_state_dict(cls, blob: dict[str, Any]) -> MarkovCounts:
        """A checkpoint's model (counts stored as a tensor by older checkpoints, a list now)."""
        model = cls(int(blob["n_states"]), blob.get("window"),
                    float(blob.get("pseudo_count", 0.0)))
        model.counts = np.asarray(blob["counts"], dtype=np.float64).copy()
        return model
