"""A valid lower bound on Σ_k υ_k at full size: Hadamard's inequality on every slot's Laplacian.

No policy can score below it, whatever it uploads or evicts. For a map G of at most V_max
frames and a next-slot frame f, with Π = I,

    u(G ∪ {f}) = −6 log det L̂ ≥ −6 Σ_{i ∈ S} log L_ii        (Hadamard: det A ≤ Π_i A_ii, A ≻ 0)

where S = G ∪ {f} without its anchor, |S| ≤ V_max, and L_ii is frame i's weighted degree inside
G ∪ {f}: at most D_i, the sum of i's V_max largest weights to any frame it could share a map
with (every instance captured so far, and the next slot's frames). So
log det L̂ ≤ Σ_{i ∈ S} max(0, log D_i) ≤ the largest such sum over any V_max instances that
include f or not — which needs no choice of map at all. A frame that loses tracking scores 0,
above every bound (each is ≤ 0). Summed over slots this bounds every plan of the episode.

It is loose where Hadamard is (degrees overlap; a map cannot hold every frame's best
neighbours at once), so the gap from a policy to the bound is an upper bound on how much it
could still gain, not an estimate of it. Π ≠ I is refused (the bound is written for Π = I).
"""

from __future__ import annotations

import numpy as np

from twinslam.policies.world_model import MapManagementEnv


def _top_sums(weights: np.ndarray, counts: np.ndarray, own: np.ndarray, k: int) -> np.ndarray:
    """Per row r: the sum of the k largest entries of ``weights[r]`` where column c stands for
    ``counts[c]`` instances, one fewer in column ``own[r]`` (the row's own instance)."""
    per_row = np.broadcast_to(counts, weights.shape).copy()
    valid = own >= 0
    per_row[np.nonzero(valid)[0], own[valid]] -= 1
    order = np.argsort(-weights, axis=1, kind="stable")
    values = np.take_along_axis(weights, order, axis=1)
    mult = np.take_along_axis(per_row, order, axis=1)
    before = np.cumsum(mult, axis=1) - mult
    take = np.clip(k - before, 0, mult)
    return np.asarray((values * take).sum(axis=1))


def _top_positive(values: np.ndarray, counts: np.ndarray, k: int) -> float:
    """Largest sum of k of the positive ``values``, value j available ``counts[j]`` times."""
    v = np.maximum(values, 0.0)
    order = np.argsort(-v, kind="stable")
    mult = counts[order]
    take = np.clip(k - (np.cumsum(mult) - mult), 0, mult)
    return float((v[order] * take).sum())


def slot_lower_bounds(env: MapManagementEnv, seed: int) -> list[float]:
    """A lower bound on υ_k of every slot of the episode ``reset(seed)`` plays."""
    if env.config.log_det_pi != 0.0:
        raise ValueError("the Hadamard bound is written for Π = I (log_det_pi = 0)")
    env.reset(seed)
    f, vmax = env.config.slot_frames, env.config.vmax
    dataset = env.dataset
    bounds = []
    for k in range(env.config.slots):
        captured = env.stream.dataset_index(np.arange((k + 1) * f))
        following = env.stream.dataset_index(np.arange((k + 1) * f, (k + 2) * f))
        frames, counts = np.unique(np.concatenate([captured, following]), return_counts=True)
        captured_counts = np.zeros_like(counts)
        idx, c = np.unique(captured, return_counts=True)
        captured_counts[np.searchsorted(frames, idx)] = c
        w = dataset.weights(frames, frames)
        # D_i: i's V_max largest weights to every other instance it could share a map with
        own = np.arange(frames.size)
        degree = _top_sums(w, counts, own, vmax)
        with np.errstate(divide="ignore"):
            log_d = np.where(degree > 0, np.log(np.maximum(degree, 1e-300)), 0.0)
        best_without = _top_positive(log_d, captured_counts, vmax)      # S ⊆ captured
        best_with_f = _top_positive(log_d, captured_counts, vmax - 1)   # S ∋ f
        at = np.searchsorted(frames, following)
        per_frame = -6.0 * np.maximum(best_without, best_with_f + np.maximum(log_d[at], 0.0))
        bounds.append(float(np.minimum(per_frame, 0.0).mean()))
    return bounds


def episode_lower_bound(env: MapManagementEnv, seed: int) -> float:
    """Σ_k of :func:`slot_lower_bounds`: no plan of this episode scores lower."""
    return float(np.sum(slot_lower_bounds(env, seed)))
