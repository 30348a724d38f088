"""The predictions every model must beat (``twinslam experiment twin-predict``): "the next slot
is like this one" and "anything may come" (log N nats). Rate models in their own right, so the
experiment scores them exactly as it scores the twins."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from twinslam.twin.rate_model import PredictiveFilter, current_state, peaked


class Persistence(PredictiveFilter):
    """``stay`` on the current state, the rest spread evenly."""

    name = "persistence"

    def __init__(self, n_states: int, stay: float = 0.9) -> None:
        if not 0.0 <= stay <= 1.0:
            raise ValueError(f"stay must be in [0, 1], got {stay}")
        super().__init__(n_states)
        self.stay = stay

    def predict(self, history: Sequence[int]) -> np.ndarray:
        return peaked(self._n, current_state(history), self.stay)

    def state_dict(self) -> dict[str, Any]:
        return {**super().state_dict(), "stay": self.stay}


class Uniform(PredictiveFilter):
    """1/N each: the score of knowing nothing."""

    name = "uniform"

    def predict(self, history: Sequence[int]) -> np.ndarray:
        return np.full(self._n, 1.0 / self._n)
