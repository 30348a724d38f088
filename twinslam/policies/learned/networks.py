"""Actor and critic of the AMM policy (paper §VII-A: GCN embedding (128, 32); critic FC
(64, 32, 32); actor FC (64, 32, 16) to a score per frame).

Both embed the state graph with two ``torch_geometric`` ``DenseGCNConv`` layers on the batched
dense adjacency (padded nodes masked out): a map of ≤ 45 frames plus 60 candidates is small
and dense (measured: 64 such graphs forward + backward in 7 ms dense vs 590 ms with a
sparse ``GCNConv`` over all pairs). The layers' parameters are ``DenseGCNConv``'s (same
initialisation, same checkpoints), but they are applied by :func:`gcn_layer` to a propagation
matrix computed once per batch (:func:`propagation`) — ``DenseGCNConv.forward`` normalises the
adjacency again in every layer of every network call, ten times an update — and the first,
widening layer propagates its 10–12 input features before the linear map rather than its 128
outputs after it (the same product, a matmul ~10× smaller; measured in a training profile).

* **Actor** — per node: [its embedding, the graph's mean embedding, the context] → a score.
  Two variants (``ACTORS``):

  - ``paper`` — the paper's AMM: the network's score is the score (its node features carry no
    ADAPT flags, :func:`~twinslam.policies.learned.state.build_state` leaves them 0).
  - ``residual`` — "ADAPT + residual RL", ours: the score starts from ADAPT's answer
    (``prior ·`` :func:`adapt_scores`, ``prior`` a learned scalar starting at 1) and the
    network adds a correction whose last layer starts near zero, so training starts from the
    myopic greedy policy and moves away from it only where the critic says the long run gains.
* **Critic** — Q(s, a) with the action as two node features (uploaded, evicted); the readout
  is the mean embedding of all nodes and the mean over the frames the action keeps in the map.
"""

from __future__ import annotations

import math

import torch
from torch import nn
from torch_geometric.nn import DenseGCNConv

from twinslam.policies.learned.state import (
    ADAPT_EVICT,
    ADAPT_UPLOAD,
    CANDIDATE,
    IN_MAP,
    NODE_FEATURES,
)


def _mlp(n_in: int, widths: tuple[int, ...], n_out: int) -> nn.Sequential:
    layers: list[nn.Module] = []
    for width in widths:
        layers += [nn.Linear(n_in, width), nn.ReLU()]
        n_in = width
    layers.append(nn.Linear(n_in, n_out))
    return nn.Sequential(*layers)


def masked_mean(h: torch.Tensor, weight: torch.Tensor) -> torch.Tensor:
    """Σ_i weight_i h_i / Σ_i weight_i over the nodes of each graph: (B, n, d) → (B, d)."""
    w = weight.unsqueeze(-1)
    return (h * w).sum(dim=1) / w.sum(dim=1).clamp_min(1e-6)


def propagation(adj: torch.Tensor) -> torch.Tensor:
    """The GCN's propagation matrix D^-1/2 (A + I) D^-1/2 of each graph (B, n, n), exactly as
    ``DenseGCNConv`` forms it: the diagonal set to 1 (padded nodes too, which keeps their
    degree ≥ 1 and their rows apart from the real nodes'), degrees clamped at 1."""
    a = adj.clone()
    idx = torch.arange(a.shape[-1])
    a[..., idx, idx] = 1.0
    d = a.sum(dim=-1).clamp(min=1).pow(-0.5)
    return d.unsqueeze(-1) * a * d.unsqueeze(-2)


def gcn_layer(conv: DenseGCNConv, h: torch.Tensor, prop: torch.Tensor,
              mask: torch.Tensor) -> torch.Tensor:
    """``conv`` applied to node features ``h`` (B, n, F) with a precomputed propagation
    matrix: P (h W) + b on the real nodes, 0 on the padded ones. P (h W) = (P h) W, so the
    matmul with P runs on the narrower side of the layer."""
    out: torch.Tensor
    if conv.in_channels < conv.out_channels:
        out = conv.lin(torch.matmul(prop, h))
    else:
        out = torch.matmul(prop, conv.lin(h))
    if conv.bias is not None:
        out = out + conv.bias
    return out * mask.unsqueeze(-1).to(h.dtype)


class GraphEmbedding(nn.Module):
    """Two graph convolutions, 128 then 32 channels, ReLU after each."""

    def __init__(self, in_features: int) -> None:
        super().__init__()
        self.conv1 = DenseGCNConv(in_features, 128)
        self.conv2 = DenseGCNConv(128, 32)

    def forward(self, x: torch.Tensor, prop: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        """Node embeddings (B, n, 32); ``prop`` is :func:`propagation` of the adjacency."""
        h = torch.relu(gcn_layer(self.conv1, x, prop, mask))
        return torch.relu(gcn_layer(self.conv2, h, prop, mask))


#: the actor variants: the paper's AMM, and ADAPT's decision plus a learned correction
ACTORS = ("paper", "residual")


class Actor(nn.Module):
    def __init__(self, context_size: int, variant: str = "residual") -> None:
        super().__init__()
        if variant not in ACTORS:
            raise ValueError(f"unknown actor {variant!r}; choose from {', '.join(ACTORS)}")
        self.variant = variant
        self.embed = GraphEmbedding(NODE_FEATURES)
        self.head = _mlp(32 + 32 + context_size, (64, 32, 16), 1)
        if variant == "residual":
            with torch.no_grad():                   # start as ADAPT plus a small correction
                last = self.head[-1]
                assert isinstance(last, nn.Linear)
                last.weight.mul_(0.01)
                last.bias.zero_()
        #: the weight of ADAPT's scores (learned; unused by the paper's actor)
        self.prior = nn.Parameter(torch.tensor(1.0 if variant == "residual" else 0.0),
                                  requires_grad=variant == "residual")

    def base_scores(self, x: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        """What the correction is added to: ADAPT's scores × prior, or 0 for the paper's."""
        if self.variant == "paper":
            return torch.zeros(mask.shape)
        return self.prior * adapt_scores(x) * mask.float()

    def correction(self, x: torch.Tensor, prop: torch.Tensor, mask: torch.Tensor,
                   context: torch.Tensor) -> torch.Tensor:
        """The learned part of the scores (B, n), zero on padded nodes."""
        h = self.embed(x, prop, mask)
        pooled = masked_mean(h, mask.float())
        n = h.shape[1]
        joint = torch.cat([h, pooled.unsqueeze(1).expand(-1, n, -1),
                           context.unsqueeze(1).expand(-1, n, -1)], dim=-1)
        scores: torch.Tensor = self.head(joint).squeeze(-1) * mask.float()
        return scores

    def forward(self, x: torch.Tensor, prop: torch.Tensor, mask: torch.Tensor,
                context: torch.Tensor) -> torch.Tensor:
        """Scores (B, n); padded nodes score 0 and are never chosen (they are not frames).
        ``prop`` is :func:`propagation` of the adjacency (a :class:`GraphBatch` carries it)."""
        return self.base_scores(x, mask) + self.correction(x, prop, mask, context)


def adapt_scores(x: torch.Tensor) -> torch.Tensor:
    """Scores whose action is exactly ADAPT's, from its flags in the node features: kept map
    frames 0, evicted ones −2; uploaded candidates +2, or −1 when ADAPT evicts them again
    (above every candidate it skips, −3, so they are still uploaded, and below every map frame
    it keeps, so they are evicted). Gaps of ≥ 1 leave room for a correction below 0.5."""
    up, ev = x[..., ADAPT_UPLOAD], x[..., ADAPT_EVICT]
    in_map, cand = x[..., IN_MAP], x[..., CANDIDATE]
    return -2.0 * ev * in_map + cand * (up * (2.0 - 3.0 * ev) - 3.0 * (1.0 - up))


class Critic(nn.Module):
    def __init__(self, context_size: int) -> None:
        super().__init__()
        self.embed = GraphEmbedding(NODE_FEATURES + 2)
        self.head = _mlp(32 + 32 + context_size, (64, 32, 32), 1)

    def forward(self, x: torch.Tensor, prop: torch.Tensor, mask: torch.Tensor,
                context: torch.Tensor, flags: torch.Tensor) -> torch.Tensor:
        """Q (B,) of taking the action ``flags`` (B, n, 2: uploaded, evicted) in the state."""
        m = mask.float()
        h = self.embed(torch.cat([x, flags], dim=-1), prop, mask)
        kept = (x[..., IN_MAP] + flags[..., 0]) * (1.0 - flags[..., 1]) * m
        joint = torch.cat([masked_mean(h, m), masked_mean(h, kept), context], dim=-1)
        value: torch.Tensor = self.head(joint).squeeze(-1)
        return value


def hard_action(scores: torch.Tensor, x: torch.Tensor, mask: torch.Tensor,
                n_upload: torch.Tensor, n_evict: torch.Tensor
                ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """The action each graph's scores stand for, batched (no Python loop over graphs — it
    was a tenth of a training update): the ``n_upload`` best-scored candidates, then the
    ``n_evict`` lowest-scored frames of the map and the uploads, ties to the earlier node
    (stable sorts), as :func:`~twinslam.policies.learned.state.select` decides one graph.

    Returns (uploaded, evicted) as (B, n) bools and the thresholds between chosen and not
    chosen (B,): t_up halfway between the |U_k|-th and the next best candidate score, t_ev
    halfway between the |C_k|-th and the next lowest score of the pool; beyond either end
    (±1e6) when nothing, or everything, is chosen."""
    with torch.no_grad():
        s = scores.detach()
        cand = (x[..., CANDIDATE] > 0.5) & mask
        in_map = (x[..., IN_MAP] > 0.5) & mask
        up, t_up = _best(s, cand, n_upload, descending=True)
        ev, t_ev = _best(s, in_map | up, n_evict, descending=False)
    return up, ev, t_up, t_ev


def _best(s: torch.Tensor, pool: torch.Tensor, k: torch.Tensor, *, descending: bool
          ) -> tuple[torch.Tensor, torch.Tensor]:
    """The ``k`` first of each row's ``pool`` in score order (bools) and the threshold
    halfway between the k-th and the next (see :func:`hard_action`)."""
    b, n = s.shape
    far = 1e6 if descending else -1e6
    keyed = s.masked_fill(~pool, -math.inf if descending else math.inf)
    ordered, order = torch.sort(keyed, dim=1, descending=descending, stable=True)
    rank = torch.empty_like(order).scatter_(1, order, torch.arange(n).expand(b, n))
    chosen = (rank < k[:, None]) & pool
    count = pool.sum(dim=1)
    below = ordered.gather(1, (k - 1).clamp(0, max(n - 1, 0))[:, None]).squeeze(1)
    above = ordered.gather(1, k.clamp(0, max(n - 1, 0))[:, None]).squeeze(1)
    threshold = torch.where((k <= 0) | (count == 0), torch.tensor(far),
                            torch.where(k >= count, torch.tensor(-far), 0.5 * (below + above)))
    return chosen, threshold


def hard_flags(scores: torch.Tensor, x: torch.Tensor, mask: torch.Tensor,
               n_upload: torch.Tensor, n_evict: torch.Tensor) -> torch.Tensor:
    """(B, n, 2) float flags (uploaded, evicted) of :func:`hard_action`."""
    up, ev, _, _ = hard_action(scores, x, mask, n_upload, n_evict)
    return torch.stack([up, ev], dim=-1).float()


def soft_flags(scores: torch.Tensor, x: torch.Tensor, mask: torch.Tensor,
               n_upload: torch.Tensor, n_evict: torch.Tensor, temperature: float
               ) -> torch.Tensor:
    """A differentiable stand-in for the action the scores stand for (the deterministic
    policy gradient needs ∂a/∂θ): a candidate is uploaded by σ((s − t_U)/T), a frame of the
    map or the uploads is evicted by σ((t_C − s)/T), with the hard action's thresholds
    (:func:`hard_action`; no gradient through them)."""
    cand = ((x[..., CANDIDATE] > 0.5) & mask).float()
    in_map = ((x[..., IN_MAP] > 0.5) & mask).float()
    _, _, t_up, t_ev = hard_action(scores, x, mask, n_upload, n_evict)
    up = torch.sigmoid((scores - t_up[:, None]) / temperature) * cand
    up = torch.where(n_upload[:, None] > 0, up, torch.zeros_like(up))
    pool = in_map + up
    ev = torch.sigmoid((t_ev[:, None] - scores) / temperature) * pool
    ev = torch.where(n_evict[:, None] > 0, ev, torch.zeros_like(ev))
    return torch.stack([up, ev], dim=-1)
