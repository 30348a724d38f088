"""Experience replay, real and artificial, and the blended batch of Algorithm 2 (lines 7–9).

A real tuple ξ_k = (s_k, a_k, r_k, s_{k+1}) is a slot the environment played; an artificial one
keeps s_k and replaces the action, the reward and the next state with what the rate model's
sampled next rate d̂_{k+1} and an emulated map update give (paper eq. 23). A batch of |Ξ|
tuples takes I from the real buffer and |Ξ| − I from the artificial one (all real while the
artificial buffer is empty, e.g. the "no artificial experiences" variant, I = |Ξ|).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from twinslam.policies.learned.networks import propagation
from twinslam.policies.learned.state import GraphState


@dataclass(frozen=True)
class Transition:
    state: GraphState
    flags: np.ndarray              #: (n, 2) uploaded / evicted of the action taken
    reward: float                  #: normalised reward
    next_state: GraphState


class ReplayBuffer:
    """The newest ``capacity`` transitions (a ring)."""

    def __init__(self, capacity: int) -> None:
        if capacity < 1:
            raise ValueError("a replay buffer needs room for at least one transition")
        self.capacity = capacity
        self._items: list[Transition] = []
        self._next = 0

    def __len__(self) -> int:
        return len(self._items)

    def add(self, item: Transition) -> None:
        if len(self._items) < self.capacity:
            self._items.append(item)
        else:
            self._items[self._next] = item
        self._next = (self._next + 1) % self.capacity

    def sample(self, count: int, rng: np.random.Generator) -> list[Transition]:
        if count <= 0 or not self._items:
            return []
        return [self._items[i] for i in rng.integers(len(self._items), size=count)]


def blended_batch(real: ReplayBuffer, artificial: ReplayBuffer, batch_size: int,
                  real_count: int, rng: np.random.Generator) -> list[Transition]:
    """I = ``real_count`` real tuples and ``batch_size`` − I artificial ones."""
    if not 0 <= real_count <= batch_size:
        raise ValueError(f"I = {real_count} real tuples in a batch of {batch_size}")
    n_art = batch_size - real_count if len(artificial) else 0
    return real.sample(batch_size - n_art, rng) + artificial.sample(n_art, rng)


@dataclass
class GraphBatch:
    """States padded to the largest graph of the batch, as the networks take them."""

    x: torch.Tensor                #: (B, n, NODE_FEATURES)
    prop: torch.Tensor             #: (B, n, n) the GCN's propagation matrix of the adjacency
    mask: torch.Tensor             #: (B, n) bool
    context: torch.Tensor          #: (B, C)
    n_upload: torch.Tensor         #: (B,) long
    n_evict: torch.Tensor          #: (B,) long


def collate(states: list[GraphState], size: int | None = None) -> GraphBatch:
    n = size or max(s.size for s in states)
    b = len(states)
    x = np.zeros((b, n, states[0].nodes.shape[1]), dtype=np.float32)
    adj = np.zeros((b, n, n), dtype=np.float32)
    mask = np.zeros((b, n), dtype=bool)
    for i, s in enumerate(states):
        x[i, :s.size] = s.nodes
        adj[i, :s.size, :s.size] = s.adjacency
        mask[i, :s.size] = True
    return GraphBatch(torch.from_numpy(x), propagation(torch.from_numpy(adj)),
                      torch.from_numpy(mask),
                      torch.from_numpy(np.stack([s.context for s in states])),
                      torch.tensor([s.n_upload for s in states]),
                      torch.tensor([s.n_evict for s in states]))


def collate_flags(transitions: list[Transition], size: int) -> torch.Tensor:
    out = np.zeros((len(transitions), size, 2), dtype=np.float32)
    for i, t in enumerate(transitions):
        out[i, :len(t.flags)] = t.flags
    return torch.from_numpy(out)
