"""The predictions every model must beat (``twinslam experiment twin-predict``): "the next slot
is like this one" and "anything may come" (log N nats). Rate models in their own right, so the
experiment scores them exactly as it scores the twins."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from twinslam.twin.rate_model import current_state, peaked


class Persistence:
    """``stay`` on the current state, the rest spread evenly."""

    name = "persistence"
    online = True

    def __init__(self, n_states: int, stay: float = 0.9) -> None:
        if not 0.0 <= stay <= 1.0:
            raise ValueError(f"stay must be in [0, 1], got {stay}")
        self._n, self.stay = n_states, stay

    @property
    def n_states(self) -> int:
        return self._n

    @property
    def feature_size(self) -> int:
        return self._n

    def reset(self) -> None:
        """Nothing to forget: the prediction reads only the newest state."""

    def observe(self, state: int) -> bool:
        return False

    def retrain(self) -> list[float]:
        return []

    def predict(self, history: Sequence[int]) -> np.ndarray:
        return peaked(self._n, current_state(history), self.stay)

    def features(self, history: Sequence[int]) -> np.ndarray:
        return self.predict(history).astype(np.float32)

    def sample_next(self, history: Sequence[int], count: int, rng: np.random.Generator
                    ) -> np.ndarray:
        return rng.choice(self._n, size=count, p=self.predict(history))

    def state_dict(self) -> dict[str, Any]:
        return {"n_states": self._n, "stay": self.stay}


class Uniform:
    """1/N each: the score of knowing nothing."""

    name = "uniform"
    online = True

    def __init__(self, n_states: int) -> None:
        self._n = n_states

    @property
    def n_states(self) -> int:
        return self._n

    @property
    def feature_size(self) -> int:
        return self._n

    def reset(self) -> None:
        """Nothing to forget."""

    def observe(self, state: int) -> bool:
        return False

    def retrain(self) -> list[float]:
        return []

    def predict(self, history: Sequence[int]) -> np.ndarray:
        return np.full(self._n, 1.0 / self._n)

    def features(self, history: Sequence[int]) -> np.ndarray:
        return self.predict(history).astype(np.float32)

    def sample_next(self, history: Sequence[int], count: int, rng: np.random.Generator
                    ) -> np.ndarray:
        return rng.integers(0, self._n, size=count)

    def state_dict(self) -> dict[str, Any]:
        return {"n_states": self._n}
