"""The paper's "LSTM" rate model (§VII-A): a classifier of the next state, used as a point
predictor. ``lstm`` scores its softmax; ``lstm-point`` its point prediction with 1 − ε on the
predicted state, as the paper uses it. As the policy's rate model (paper's "Proposed (LSTM)")
its features are the one-hot point prediction and its artificial next states that prediction
(it has no distribution to sample). Learned weights (not ``online``), retrained every W slots.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
from torch import nn

from twinslam.twin.rate_history import fit, history_windows, latest_window, one_hot
from twinslam.twin.rate_model import peaked


@dataclass(frozen=True)
class LstmConfig:
    n_states: int = 2
    history: int = 8
    lstm_hidden: int = 300
    buffer_slots: int = 600
    retrain_every: int = 100
    steps_per_retrain: int = 100
    batch_size: int = 64
    learning_rate: float = 3e-3
    seed: int = 0
    #: None: predict the softmax (``lstm``); else the point prediction with 1 − ε on it
    #: (``lstm-point``)
    point_epsilon: float | None = None


class LstmNetwork(nn.Module):
    """2×LSTM(300) → FC(256, 128) → logits of d_{k+1} (the twin's encoder trunk, no latent)."""

    def __init__(self, n_states: int, lstm_hidden: int = 300) -> None:
        super().__init__()
        self.lstm = nn.LSTM(n_states, lstm_hidden, num_layers=2, batch_first=True)
        self.head = nn.Sequential(nn.Linear(lstm_hidden, 256), nn.ReLU(), nn.Linear(256, 128),
                                  nn.ReLU(), nn.Linear(128, n_states))

    def forward(self, windows: torch.Tensor) -> torch.Tensor:
        out, _ = self.lstm(windows)
        logits: torch.Tensor = self.head(out[:, -1])
        return logits


class LstmPredictor:
    """Trained on the next state like a classifier but used as a point predictor — it outputs
    one next state, not a distribution. Its transition matrix is what those predictions imply:
    row i = frequencies of the predicted next states over the recent histories that end in
    state i."""

    online = False

    def __init__(self, config: LstmConfig | None = None) -> None:
        self.config = config or LstmConfig()
        torch.manual_seed(self.config.seed)
        self._rng = np.random.default_rng(self.config.seed)
        self.network = LstmNetwork(self.config.n_states, self.config.lstm_hidden)
        self.states: list[int] = []
        self._since = 0
        self.name = "lstm" if self.config.point_epsilon is None else "lstm-point"

    @property
    def n_states(self) -> int:
        return self.config.n_states

    @property
    def feature_size(self) -> int:
        return self.config.n_states

    def reset(self) -> None:
        """Nothing: the learned weights carry over from run to run."""

    def observe(self, state: int) -> bool:
        """Record a state; True when a retrain is due (every ``retrain_every`` slots)."""
        self.states.append(int(state))
        del self.states[:-max(self.config.buffer_slots, self.config.history) - 1]
        self._since += 1
        return self._since >= self.config.retrain_every

    def retrain(self) -> list[float]:
        cfg = self.config
        windows, targets = history_windows(np.array(self.states), cfg.history, cfg.n_states)
        self._since = 0
        if len(targets) == 0:
            return []
        loss = nn.CrossEntropyLoss()
        return fit(self.network, lambda w, t: loss(self.network(w), t), windows, targets,
                   cfg.steps_per_retrain, cfg.batch_size, cfg.learning_rate, self._rng)

    def predict(self, history: Sequence[int]) -> np.ndarray:
        """p(d_{k+1}) after ``history``: the softmax, or the point prediction made a
        distribution (``point_epsilon``)."""
        eps = self.config.point_epsilon
        if eps is None:
            return self.probabilities(history)
        return peaked(self.config.n_states, self.point(history), 1.0 - eps)

    def features(self, history: Sequence[int]) -> np.ndarray:
        out = np.zeros(self.config.n_states, dtype=np.float32)
        out[self.point(history)] = 1.0
        return out

    def sample_next(self, history: Sequence[int], count: int, rng: np.random.Generator
                    ) -> np.ndarray:
        return np.full(count, self.point(history), dtype=np.int64)

    @torch.no_grad()
    def point(self, states: Sequence[int]) -> int:
        """The point prediction of d_{k+1} after the history ``states``."""
        x = latest_window(states, self.config.history, self.config.n_states)
        return int(self.network(x).argmax(dim=-1))

    @torch.no_grad()
    def probabilities(self, states: Sequence[int]) -> np.ndarray:
        """The classifier's softmax over d_{k+1} after ``states`` (the distribution the point
        prediction is the arg-max of)."""
        x = latest_window(states, self.config.history, self.config.n_states)
        return torch.softmax(self.network(x), dim=-1)[0].numpy().astype(np.float64)

    @torch.no_grad()
    def transition_matrix(self, recent: int = 100) -> np.ndarray:
        """Rows from the predictions after each of the last ``recent`` histories; a state that
        ends none of them is answered from a history of that state alone."""
        cfg = self.config
        n = cfg.n_states
        s = np.array(self.states[-(recent + cfg.history):], dtype=np.int64)
        counts = np.zeros((n, n))
        if s.size >= cfg.history:
            idx = np.arange(cfg.history)[None, :] + np.arange(s.size - cfg.history + 1)[:, None]
            x = torch.from_numpy(one_hot(s[idx], n))
            pred = self.network(x).argmax(dim=-1).numpy()
            np.add.at(counts, (s[idx[:, -1]], pred), 1.0)
        for i in range(n):
            if counts[i].sum() == 0:
                counts[i, self.point([i] * cfg.history)] = 1.0
        return np.asarray(counts / counts.sum(axis=1, keepdims=True))

    def state_dict(self) -> dict[str, Any]:
        return {"config": self.config.__dict__, "network": self.network.state_dict()}

    @classmethod
    def from_state_dict(cls, blob: dict[str, Any]) -> LstmPredictor:
        predictor = cls(LstmConfig(**blob["config"]))
        predictor.network.load_state_dict(blob["network"])
        return predictor
