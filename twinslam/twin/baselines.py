"""What the twin is compared with (paper §VII-A): a Markov model-driven estimator and an LSTM
point predictor. Both learn from the same state sequence as the twin and answer the same
question — the current interval's transition matrix — so one error metric serves all three.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from torch import nn

from twinslam.twin.rate_history import fit, history_windows, latest_window, one_hot


class MarkovMle:
    """Maximum-likelihood transition counts: P̂[i, j] = n_ij / n_i over the whole history, or
    over the last ``window`` transitions. A state never left yet has a uniform row.

    The counts are kept up to date as states arrive (a transition leaving the window is taken
    off again), so a query costs O(N²) however long the history — the learned policy asks once
    per slot over 10⁴ slots."""

    def __init__(self, n_states: int, window: int | None = None) -> None:
        if window is not None and window < 1:
            raise ValueError("window must be >= 1 transition")
        self.n_states, self.window = n_states, window
        self.counts = np.zeros((n_states, n_states))
        self._recent: list[int] = []        #: the window's states (the last one only if whole)

    def observe(self, state: int) -> None:
        s = int(state)
        if self._recent:
            self.counts[self._recent[-1], s] += 1.0
        self._recent.append(s)
        keep = 1 if self.window is None else self.window + 1
        while len(self._recent) > keep:
            if self.window is not None:
                self.counts[self._recent[0], self._recent[1]] -= 1.0
            del self._recent[0]

    def transition_matrix(self) -> np.ndarray:
        rows = self.counts.sum(axis=1, keepdims=True)
        return np.where(rows > 0, self.counts / np.maximum(rows, 1.0), 1.0 / self.n_states)


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


class LstmNetwork(nn.Module):
    """2×LSTM(300) → FC(256, 128) → logits of d_{k+1} (the twin's encoder trunk, no latent)."""

    def __init__(self, n_states: int, lstm_hidden: int = 300) -> None:
        super().__init__()
        self.lstm = nn.LSTM(n_states, lstm_hidden, num_layers=2, batch_first=True)
        self.head = nn.Sequential(nn.Linear(lstm_hidden, 256), nn.ReLU(), nn.Linear(256, 128),
                                  nn.ReLU(), nn.Linear(128, n_states))

    def forward(self, windows: torch.Tensor) -> torch.Tensor:
        out, _ = self.lstm(windows)
        return self.head(out[:, -1])


class LstmPredictor:
    """The paper's "LSTM": trained on the next state like a classifier but used as a point
    predictor — it outputs one next state, not a distribution. Its transition matrix is what
    those predictions imply: row i = frequencies of the predicted next states over the recent
    histories that end in state i."""

    def __init__(self, config: LstmConfig | None = None) -> None:
        self.config = config or LstmConfig()
        torch.manual_seed(self.config.seed)
        self._rng = np.random.default_rng(self.config.seed)
        self.network = LstmNetwork(self.config.n_states, self.config.lstm_hidden)
        self.states: list[int] = []
        self._since = 0

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

    @torch.no_grad()
    def predict(self, states: list[int]) -> int:
        """The point prediction of d_{k+1} after the history ``states``."""
        x = latest_window(states, self.config.history, self.config.n_states)
        return int(self.network(x).argmax(dim=-1))

    @torch.no_grad()
    def probabilities(self, states: list[int]) -> np.ndarray:
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
                counts[i, self.predict([i] * cfg.history)] = 1.0
        return counts / counts.sum(axis=1, keepdims=True)
