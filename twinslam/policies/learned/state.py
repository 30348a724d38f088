"""The augmented state of one slot as a graph, and the action a score per frame stands for.

Paper §VI-A: the state is the map, the slot's candidate frames and the rate history,
augmented with the rate model's latent features. Here the map frames and the candidates are
the nodes of one weighted graph (edge weight log(1 + w(f, f')), w the covisibility weight), each
node with features a GCN can combine with its neighbours':

    in map · candidate · anchor · age in slots · weight to the map · weight to the candidates ·
    weight to the newest candidates · share of nodes it is covisible with ·
    ADAPT would upload it · ADAPT would evict it

The last two give the residual actor the myopic greedy answer to start from (AdaptSLAM's
logdet rule, one numba call per slot); what it has to learn is when the long run wants
something else. The paper's AMM gets them as zeros. The
graph-level context is Theorem 1's cardinalities, the one-hot rate history and the rate model's
features.

An action is a score per node: U_k = the |U_k| best-scored candidates, C_k = the |C_k|
lowest-scored frames of V_k ∪ U_k (Theorem 1's sizes, so every action is feasible).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from twinslam.policies.actions import MapAction, SlotObservation
from twinslam.policies.rules import adapt_action

NODE_FEATURES = 10
#: the node feature columns other modules read (the order of the list above)
IN_MAP, CANDIDATE, ADAPT_UPLOAD, ADAPT_EVICT = 0, 1, 8, 9
#: scale of map sizes and ages in the features (the paper's largest V_max); fixed, not the
#: configured default (twinslam.slot_protocol.table1): trained checkpoints depend on it
SIZE_SCALE = 45.0
#: log(1 + w) of a strong covisibility edge is ~5-6; features are divided by this
LOG_WEIGHT_SCALE = 8.0
NEWEST = 10                      #: candidates that stand in for the next slot's frames


@dataclass(frozen=True)
class GraphState:
    """One slot's augmented state; nodes are the map frames (oldest first), then the
    candidates (in capture order)."""

    frames: tuple[int, ...]          #: frame ids of the nodes
    nodes: np.ndarray                #: (n, NODE_FEATURES) float32
    adjacency: np.ndarray            #: (n, n) float16, log(1 + w), zero diagonal
    context: np.ndarray              #: (C,) float32
    n_map: int
    n_upload: int
    n_evict: int

    @property
    def size(self) -> int:
        return len(self.frames)


def context_size(history: int, n_states: int, rate_features: int) -> int:
    return 3 + history * n_states + rate_features


def build_state(obs: SlotObservation, rate_features: np.ndarray, history: int,
                adapt_features: bool = True) -> GraphState:
    """The graph state of ``obs``; ``rate_features`` come from the rate model and
    ``history`` is the number of rate states the context holds (shorter histories are padded
    with their oldest state, as the rate models do). ``adapt_features=False`` (the paper's
    AMM) leaves ADAPT's two flag columns 0: the actor sees no greedy answer."""
    v, f = list(obs.map_frames), list(obs.candidates)
    frames = v + f
    nv, n = len(v), len(v) + len(f)
    w = np.asarray(obs.weight_block(frames, frames), dtype=np.float64)
    log_w = np.log1p(w)
    x = np.zeros((n, NODE_FEATURES), dtype=np.float32)
    x[:nv, IN_MAP] = 1.0
    x[nv:, CANDIDATE] = 1.0
    if nv:
        x[0, 2] = 1.0
    newest_id = max(f) if f else (max(v) if v else 0)
    per_slot = max(len(f), 1)
    x[:, 3] = (newest_id - np.asarray(frames, dtype=np.float64)) / per_slot / SIZE_SCALE
    x[:, 4] = log_w[:, :nv].sum(axis=1) / LOG_WEIGHT_SCALE / SIZE_SCALE
    x[:, 5] = log_w[:, nv:].sum(axis=1) / LOG_WEIGHT_SCALE / SIZE_SCALE
    x[:, 6] = log_w[:, n - min(NEWEST, len(f)):].sum(axis=1) / LOG_WEIGHT_SCALE / NEWEST
    x[:, 7] = (w > 0).sum(axis=1) / max(n - 1, 1)
    if adapt_features:
        greedy = adapt_action(v, f, w, obs.n_upload, obs.n_evict)
        at = {fr: i for i, fr in enumerate(frames)}
        x[[at[u] for u in greedy.upload], ADAPT_UPLOAD] = 1.0
        x[[at[e] for e in greedy.evict], ADAPT_EVICT] = 1.0
    hist = list(obs.rate_history)[-history:]
    hist = [hist[0]] * (history - len(hist)) + hist if hist else [0] * history
    one_hot = np.eye(obs.n_states, dtype=np.float32)[hist].ravel()
    context = np.concatenate([
        np.array([obs.n_upload / per_slot, obs.n_evict / SIZE_SCALE, nv / SIZE_SCALE],
                 dtype=np.float32), one_hot, np.asarray(rate_features, dtype=np.float32)])
    return GraphState(tuple(frames), x, log_w.astype(np.float16), context, nv, obs.n_upload,
                      obs.n_evict)


def select(scores: np.ndarray, n_map: int, n_upload: int, n_evict: int) -> np.ndarray:
    """(n, 2) flags (uploaded, evicted) of the action ``scores`` stand for, with the map
    frames first: the ``n_upload`` best-scored candidates, then the ``n_evict`` lowest-scored
    frames of the map and the uploads. Ties go to the earlier node (a stable sort)."""
    s = np.asarray(scores, dtype=np.float64)
    flags = np.zeros((s.size, 2), dtype=np.float32)
    cand = n_map + np.argsort(-s[n_map:], kind="stable")[:n_upload]
    flags[cand, 0] = 1.0
    pool = np.concatenate([np.arange(n_map), np.sort(cand)])
    flags[pool[np.argsort(s[pool], kind="stable")[:n_evict]], 1] = 1.0
    return flags


def action_from_scores(state: GraphState, scores: np.ndarray) -> tuple[MapAction, np.ndarray]:
    """Theorem 1's action a score per node stands for, and its flags (see :func:`select`)."""
    s = np.asarray(scores, dtype=np.float64)
    if s.shape != (state.size,):
        raise ValueError(f"{s.shape[0] if s.ndim else 0} scores for {state.size} nodes")
    flags = select(s, state.n_map, state.n_upload, state.n_evict)
    frames = np.asarray(state.frames, dtype=np.int64)
    return MapAction(sorted(frames[flags[:, 0] > 0].tolist()),
                     sorted(frames[flags[:, 1] > 0].tolist())), flags
