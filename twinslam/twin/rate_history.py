"""Rate histories as learning data, and how an estimated transition matrix is scored.

The twin and its baselines all learn from the same thing: the sequence of quantised uplink
states d_0, d_1, … (one per slot). A training example is a history window
d_k = [d_{k−τ} … d_k] (one-hot, τ+1 steps) and its successor d_{k+1}.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np
import torch
from torch import nn


def one_hot(states: np.ndarray, n_states: int) -> np.ndarray:
    """(…, N) float32 one-hot rows of integer states."""
    s = np.asarray(states, dtype=np.int64)
    if s.size and (s.min() < 0 or s.max() >= n_states):
        raise ValueError(f"states must lie in [0, {n_states}), got {s.min()}..{s.max()}")
    return np.eye(n_states, dtype=np.float32)[s]


def history_windows(states: np.ndarray, history: int, n_states: int
                    ) -> tuple[torch.Tensor, torch.Tensor]:
    """Every (d_k window, d_{k+1}) pair of a state sequence: windows (M, history, N) one-hot,
    targets (M,) long. Empty tensors when the sequence is shorter than ``history`` + 1."""
    s = np.asarray(states, dtype=np.int64)
    m = s.size - history
    if m <= 0:
        return (torch.zeros((0, history, n_states)), torch.zeros(0, dtype=torch.long))
    idx = np.arange(history)[None, :] + np.arange(m)[:, None]
    return (torch.from_numpy(one_hot(s[idx], n_states)), torch.from_numpy(s[history:].copy()))


def latest_window(states: Sequence[int], history: int, n_states: int) -> torch.Tensor:
    """The newest ``history`` states as a (1, history, N) one-hot batch; a shorter sequence is
    padded at the front with its oldest state (no states at all: state 0)."""
    s = list(states[-history:])
    s = [s[0]] * (history - len(s)) + s if s else [0] * history
    return torch.from_numpy(one_hot(np.array(s), n_states))[None]


def transition_error(estimate: np.ndarray, truth: np.ndarray) -> float:
    """Mean absolute difference over all N² entries of two transition matrices — the error
    of every UDT figure (paper Figs 4 and 5)."""
    a, b = np.asarray(estimate, dtype=np.float64), np.asarray(truth, dtype=np.float64)
    if a.shape != b.shape:
        raise ValueError(f"matrices differ in shape: {a.shape} vs {b.shape}")
    return float(np.abs(a - b).mean())


def fit(network: nn.Module, loss_fn: Callable[[torch.Tensor, torch.Tensor], torch.Tensor],
        windows: torch.Tensor, targets: torch.Tensor, steps: int, batch_size: int,
        learning_rate: float, rng: np.random.Generator) -> list[float]:
    """``steps`` Adam steps on random mini-batches of (window, target) pairs, in place, from
    the network's current weights (the warm start of Algorithm 1); returns every step's loss.
    """
    opt = torch.optim.Adam(network.parameters(), lr=learning_rate)
    network.train()
    trace: list[float] = []
    for _ in range(steps):
        idx = torch.from_numpy(rng.integers(0, len(targets), batch_size))
        loss = loss_fn(windows[idx], targets[idx])
        opt.zero_grad()
        loss.backward()
        opt.step()
        trace.append(float(loss.detach()))
    network.eval()
    return trace
