"""Map-management policies behind one interface, used by the simulator and the edge node.

A policy sees a :class:`~simulator.env.SlotObservation` and returns U_k and C_k of the sizes
Theorem 1 fixes. The rule-based ones are the paper's benchmarks (§VII):

* **LFF** — latest frames first: upload the last |U_k| frames, evict the oldest map frames.
* **PU** — periodical uploading: upload frames spread evenly over the slot, evict the oldest.
* **ADAPT** — AdaptSLAM's rule (Chen et al., INFOCOM'23): greedily keep the frames that
  maximise logdet of the grounded covisibility Laplacian; here first the uploads (greedy
  additions to the map), then the evictions (greedy removals), each step choosing the frame
  with the largest resulting logdet. logdet of a Laplacian is monotone log-submodular
  (Khosoussi et al.), so greedy additions carry the (1 - 1/e) guarantee.
* **random** — a sanity floor.
"""

from __future__ import annotations

import math
from typing import Protocol

import numpy as np

from edge_mapper.uncertainty import batched_logdet_spd, laplacian, logdet_spd, reduced_laplacian
from simulator.env import MapAction, SlotObservation

_TIE_RTOL = 1e-9


class MapPolicy(Protocol):
    name: str

    def reset(self, seed: int | None = None) -> None: ...

    def decide(self, obs: SlotObservation) -> MapAction: ...


def _evict_oldest(obs: SlotObservation, upload: list[int]) -> list[int]:
    return sorted(obs.map_frames + upload)[:obs.n_evict]


def pick_best(values: np.ndarray) -> int:
    """Index of the largest value; near-ties (relative 1e-9) go to the lowest index."""
    best = float(np.max(values))
    if best == -math.inf:
        return 0
    return int(np.flatnonzero(values >= best - _TIE_RTOL * max(1.0, abs(best)))[0])


class LatestFrameFirst:
    name = "lff"

    def reset(self, seed: int | None = None) -> None:
        pass

    def decide(self, obs: SlotObservation) -> MapAction:
        upload = obs.candidates[len(obs.candidates) - obs.n_upload:] if obs.n_upload else []
        return MapAction(upload, _evict_oldest(obs, upload))


class PeriodicalUploading:
    name = "pu"

    def reset(self, seed: int | None = None) -> None:
        pass

    def decide(self, obs: SlotObservation) -> MapAction:
        m = len(obs.candidates)
        if obs.n_upload == 0:
            return MapAction([], _evict_oldest(obs, []))
        # n evenly spaced frames, the last one being the slot's last frame
        idx = [m - 1 - round(i * m / obs.n_upload) for i in range(obs.n_upload)][::-1]
        upload = [obs.candidates[i] for i in idx]
        return MapAction(upload, _evict_oldest(obs, upload))


class RandomPolicy:
    name = "random"

    def __init__(self, seed: int = 0) -> None:
        self._rng = np.random.default_rng(seed)

    def reset(self, seed: int | None = None) -> None:
        if seed is not None:
            self._rng = np.random.default_rng(seed)

    def decide(self, obs: SlotObservation) -> MapAction:
        upload = sorted(self._rng.choice(obs.candidates, obs.n_upload, replace=False).tolist())
        pool = obs.map_frames + upload
        evict = sorted(self._rng.choice(pool, obs.n_evict, replace=False).tolist())
        return MapAction(upload, evict)


# ---------------------------------------------------------------------------------------------
# ADAPT: incremental greedy


def greedy_additions(set_w: np.ndarray, cand_set_w: np.ndarray, cand_w: np.ndarray,
                     count: int) -> list[int]:
    """Greedily add ``count`` candidates to a frame set, each maximising logdet(L̂).

    ``set_w`` (n×n) are the set's weights, ``cand_set_w`` (m×n) candidates to set, ``cand_w``
    (m×m) candidates among themselves. Grounding the *candidate* (Kirchhoff) makes
    L̂(S ∪ {v}) = L(S) + diag(b_v): every remaining candidate of a round is scored by one batched
    Cholesky of a shared Laplacian plus a diagonal, and the chosen frame enters L(S) as a border
    and a diagonal update, never rebuilt from point sets. Returns candidate indices in order.
    """
    m = cand_set_w.shape[0]
    chosen: list[int] = []
    lap = laplacian(set_w)
    b = cand_set_w.astype(np.float64).copy()         # weights of every candidate to S
    remaining = list(range(m))
    if set_w.shape[0] == 0 and count > 0:
        # An empty set: start from the candidate most connected to the others.
        first = pick_best(cand_w.sum(axis=1).astype(np.float64))
        chosen.append(first)
        remaining.remove(first)
        lap = np.zeros((1, 1))
        b = cand_w[:, [first]].astype(np.float64)
    while len(chosen) < count:
        n = lap.shape[0]
        rem = np.array(remaining)
        mats = np.broadcast_to(lap, (rem.size, n, n)).copy()
        diag = np.arange(n)
        mats[:, diag, diag] += b[rem]
        scores = batched_logdet_spd(mats)
        v = int(rem[pick_best(scores)])
        chosen.append(v)
        remaining.remove(v)
        # Border L(S) with v: degrees of S grow by b_v, v's degree is sum(b_v).
        bv = b[v]
        new = np.zeros((n + 1, n + 1))
        new[:n, :n] = lap + np.diag(bv)
        new[:n, n] = new[n, :n] = -bv
        new[n, n] = bv.sum()
        lap = new
        b = np.concatenate([b, cand_w[:, [v]].astype(np.float64)], axis=1)
    return chosen


def greedy_removals(set_w: np.ndarray, count: int) -> list[int]:
    """Greedily remove ``count`` frames, each time the one whose removal keeps logdet highest.

    For all frames v at once: L(S \\ v) is L(S) without v's row and column and with v's weights
    taken off its neighbours' degrees; grounded at the first remaining frame, the whole round is
    one batched Cholesky.
    """
    w = set_w.astype(np.float64)
    alive = list(range(w.shape[0]))
    removed: list[int] = []
    for _ in range(count):
        t = len(alive)
        if t <= 2:
            # Any removal leaves <= 1 frame (logdet 0): drop the oldest.
            v = alive[0]
        else:
            w_alive = w[np.ix_(alive, alive)]
            keep = np.array([[j for j in range(t) if j != i] for i in range(t)])  # (t, t-1)
            mats = laplacian(w_alive)[keep[:, :, None], keep[:, None, :]]
            idx = np.arange(t - 1)
            mats[:, idx, idx] -= w_alive[np.arange(t)[:, None], keep]           # v's weights
            scores = batched_logdet_spd(mats[:, 1:, 1:])
            v = alive[pick_best(scores)]
        removed.append(v)
        alive.remove(v)
    return removed


def naive_greedy(weights: np.ndarray, start: list[int], pool: list[int], n_add: int,
                 n_remove: int) -> tuple[list[int], list[int]]:
    """Reference greedy that recomputes every determinant from scratch (for tests and bench)."""
    current = list(start)
    added: list[int] = []
    remaining = list(pool)
    for _ in range(n_add):
        if not current:
            scores = np.array([weights[v, remaining].sum() for v in remaining], dtype=float)
        else:
            scores = np.array([logdet_spd(reduced_laplacian(
                weights[np.ix_([*current, v], [*current, v])])) for v in remaining])
        v = remaining[pick_best(scores)]
        added.append(v)
        current.append(v)
        remaining.remove(v)
    removed: list[int] = []
    order = sorted(current)
    for _ in range(n_remove):
        if len(order) <= 2:
            v = order[0]
        else:
            scores = np.array([logdet_spd(reduced_laplacian(
                weights[np.ix_([x for x in order if x != v], [x for x in order if x != v])]))
                for v in order])
            v = order[pick_best(scores)]
        removed.append(v)
        order.remove(v)
    return added, removed


class Adapt:
    """ADAPT benchmark: greedy logdet maximisation of the kept map (AdaptSLAM's rule)."""

    name = "adapt"

    def reset(self, seed: int | None = None) -> None:
        pass

    def decide(self, obs: SlotObservation) -> MapAction:
        v, f = obs.map_frames, obs.candidates
        set_w = obs.weight_block(v, v) if v else np.zeros((0, 0))
        cand_set_w = obs.weight_block(f, v) if v else np.zeros((len(f), 0))
        cand_w = obs.weight_block(f, f)
        picks = greedy_additions(set_w, cand_set_w, cand_w, obs.n_upload)
        upload = sorted(f[i] for i in picks)
        if obs.n_evict == 0:
            return MapAction(upload, [])
        union = sorted(v + upload)
        pos = {fid: i for i, fid in enumerate(union)}
        # The union's weights from the blocks already fetched (map, map-candidate, candidates).
        w = np.zeros((len(union), len(union)))
        vi, ui = [pos[x] for x in v], [pos[f[i]] for i in picks]
        if v:
            w[np.ix_(vi, vi)] = set_w
            w[np.ix_(ui, vi)] = cand_set_w[picks]
            w[np.ix_(vi, ui)] = cand_set_w[picks].T
        w[np.ix_(ui, ui)] = cand_w[np.ix_(picks, picks)]
        evict = sorted(union[i] for i in greedy_removals(w, obs.n_evict))
        return MapAction(upload, evict)


POLICIES = {"lff": LatestFrameFirst, "pu": PeriodicalUploading, "adapt": Adapt,
            "random": RandomPolicy}


def make_policy(name: str) -> MapPolicy:
    try:
        return POLICIES[name]()
    except KeyError:
        raise ValueError(f"unknown policy {name!r}; choose from {sorted(POLICIES)} "
                         "(or 'oracle' in the simulator)") from None
