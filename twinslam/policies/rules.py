"""The paper's rule policies and the random control, used by the simulator and the edge node.

A policy (:class:`~twinslam.policies.protocol.MapPolicy`) sees a
:class:`~twinslam.policies.actions.SlotObservation` and returns U_k and C_k of the sizes
Theorem 1 fixes. The rule-based ones are the paper's benchmarks (§VII):

* **LFF** — latest frames first: upload the last |U_k| frames, evict the oldest map frames
  (those longest in the map, :meth:`SlotObservation.entry_order`).
* **PU** — periodical uploading: upload frames spread evenly over the slot, evict the oldest.
* **ADAPT** — AdaptSLAM's rule (Chen et al., INFOCOM'23): greedily keep the frames that
  maximise logdet of the grounded covisibility Laplacian; here first the uploads (greedy
  additions to the map), then the evictions (greedy removals), each step choosing the frame
  with the largest resulting logdet. Greedy is a heuristic here: the log-submodularity
  that gives greedy its (1 - 1/e) guarantee (Khosoussi et al.) holds for choosing *edges* of a
  graph on fixed vertices, not for choosing frames (vertices, each bringing all its edges),
  so no approximation bound is claimed (docs/architecture.md §2).
* **random** — a sanity floor.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from twinslam.policies.actions import MapAction, SlotObservation
from twinslam.policies.protocol import MapPolicy
from twinslam.uncertainty import greedy_kernels
from twinslam.uncertainty.laplacian_factorization import BOUND_RTOL, PIVOT_RTOL, TIE_RTOL


def _evict_oldest(obs: SlotObservation, upload: list[int]) -> list[int]:
    """The |C_k| keyframes longest in the map, this slot's uploads last. By time in the map,
    not by id: a keyframe restored from the archive is old by capture and would be the first
    evicted at the very next slot (95.9 % of LFF's restores were, docs/results/restores.md),
    a copy adopted from another device's map tagged as the newest the last, ever. The same
    keyframes as by id where the map only adds uploads (the paper's setting)."""
    return sorted((obs.entry_order() + sorted(upload))[:obs.n_evict])


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
    (m×m) candidates among themselves. A candidate is scored against one factorisation of the
    set (matrix determinant lemma on the few frames it touches), and the chosen frame borders
    the set's inverse Laplacian instead of refactorising it. Every candidate has a proven
    upper bound on its score: a Hadamard bound from the diagonal of the inverse
    (``tighten_addition_bounds``), and after a pick the previous score raised by Rayleigh
    monotonicity (``raise_addition_bounds``), whichever is lower. A round scores candidates in
    order of that bound and stops once no bound can reach the best score within the tie
    tolerance, so it picks exactly what scoring all of them would. The whole loop is one
    compiled call (:mod:`twinslam.uncertainty.greedy_kernels`). Returns candidate indices in pick
    order.
    """
    if count > cand_set_w.shape[0]:
        raise ValueError(f"cannot add {count} of {cand_set_w.shape[0]} candidates")
    picks = greedy_kernels.greedy_additions(
        np.ascontiguousarray(set_w, dtype=np.float64),
        np.ascontiguousarray(cand_set_w, dtype=np.float64),
        np.ascontiguousarray(cand_w, dtype=np.float64), int(count), TIE_RTOL, BOUND_RTOL,
        PIVOT_RTOL)
    return [int(i) for i in picks]


def greedy_removals(set_w: np.ndarray, count: int) -> list[int]:
    """Greedily remove ``count`` frames, each time the one whose removal keeps logdet highest.

    Every frame's removal is scored from the set's inverse Laplacian (a downdate on the
    frame's neighbours), and the removal itself downdates that inverse. Near-ties go to the
    oldest frame; when any removal leaves <= 1 frame, the oldest goes.
    """
    n = np.asarray(set_w).shape[0]
    if count > n:
        raise ValueError(f"cannot remove {count} of {n} frames")
    picks = greedy_kernels.greedy_removals(np.ascontiguousarray(set_w, dtype=np.float64),
                                           int(count), TIE_RTOL, BOUND_RTOL, PIVOT_RTOL)
    return [int(i) for i in picks]


class Adapt:
    """ADAPT benchmark: greedy logdet maximisation of the kept map (AdaptSLAM's rule)."""

    name = "adapt"

    def reset(self, seed: int | None = None) -> None:
        pass

    def decide(self, obs: SlotObservation) -> MapAction:
        everything = obs.map_frames + obs.candidates   # one weight query serves both stages
        return adapt_action(obs.map_frames, obs.candidates,
                            obs.weight_block(everything, everything), obs.n_upload, obs.n_evict)


def adapt_action(map_frames: list[int], candidates: list[int], weights: np.ndarray,
                 n_upload: int, n_evict: int) -> MapAction:
    """ADAPT's decision from the weights among ``map_frames + candidates`` (in that order);
    the learned policy reads it as a feature of the same block it already gathered."""
    v, f, w = map_frames, candidates, weights
    nv = len(v)
    everything = v + f
    picks = greedy_additions(w[:nv, :nv], w[nv:, :nv], w[nv:, nv:], n_upload)
    upload = sorted(f[i] for i in picks)
    if n_evict == 0:
        return MapAction(upload, [])
    keep = sorted([*range(nv), *(nv + i for i in picks)], key=everything.__getitem__)
    union = [everything[i] for i in keep]
    evict = sorted(union[i] for i in greedy_removals(w[np.ix_(keep, keep)], n_evict))
    return MapAction(upload, evict)


POLICIES: dict[str, Callable[[], MapPolicy]] = {
    "lff": LatestFrameFirst, "pu": PeriodicalUploading, "adapt": Adapt, "random": RandomPolicy}


def make_rule_policy(name: str) -> MapPolicy:
    """A rule-based policy by name (the learned ones are reached through
    :mod:`twinslam.policies.registry`, so that nothing here needs torch)."""
    try:
        return POLICIES[name]()
    except KeyError:
        raise ValueError(f"unknown policy {name!r}; choose from {sorted(POLICIES)}") from None
