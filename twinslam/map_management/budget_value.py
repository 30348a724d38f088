"""What a keyframe budget is worth to one device: its predicted tracked share as a function of
the budget, the curve the ``twin`` allocator splits V_total by
(:mod:`twinslam.map_management.allocation`).

Only what the edge knows when it decides: the device's map (each keyframe's point ids), the
frames of its last slot (their point ids; these stand for the next slot's frames, which the
device has not seen yet) and the uploads its rate twin expects next slot. With a budget of b
keyframes the map after the next update holds the expected uploads (taken evenly from the last
slot's frames, policy-neutral) and the b − uploads keyframes most covisible with the last
slot's frames. A frame counts as tracked when it shares at least ``min_shared`` points with
that map — the rule the device lives by (:mod:`twinslam.common.tracking_rule`). The uploaded
frames themselves are left out of the score (they would share every point with themselves).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np


def expected_uploads(state_probs: Sequence[float], state_rates_mbps: Sequence[float],
                     alpha_mbit: float, d_req_s: float, slot_frames: int) -> float:
    """E[|U_{k+1}|] under a predictive distribution over the rate states: Σ_s p(s)·⌊d_s D_req/α⌋
    (Theorem 1's count), at most a slot's frames."""
    p = np.asarray(state_probs, dtype=np.float64)
    rates = np.asarray(state_rates_mbps, dtype=np.float64)
    if p.shape != rates.shape or p.size == 0:
        raise ValueError(f"{p.size} state probabilities for {rates.size} state rates")
    counts = np.minimum(np.floor(rates * d_req_s / alpha_mbit + 1e-9), slot_frames)
    return float(np.dot(p / p.sum(), counts))


def budget_value(keyframes: Sequence[np.ndarray], frames: Sequence[np.ndarray],
                 uploads: float, min_shared: int, max_budget: int) -> np.ndarray:
    """value[b], b = 0 … ``max_budget``: the share of ``frames`` (point-id arrays) that would
    share at least ``min_shared`` points with a map of b keyframes — ``round(uploads)`` of
    them the frames' own uploads, the rest of ``keyframes`` (point-id arrays) by covisibility
    with the frames. Non-decreasing in b; all zeros without frames to score."""
    if min_shared < 1 or max_budget < 0:
        raise ValueError("min_shared must be >= 1 and max_budget >= 0")
    n_up = min(round(max(uploads, 0.0)), len(frames))
    up_rows = (np.unique(np.linspace(0, len(frames) - 1, n_up).round().astype(np.int64))
               if n_up else np.zeros(0, dtype=np.int64))
    scored = [f for i, f in enumerate(frames) if i not in set(up_rows.tolist())]
    if not scored:
        return np.zeros(max_budget + 1)
    frame_ids = [np.asarray(f, dtype=np.int64) for f in scored]
    ranked = _by_covisibility([np.asarray(k, dtype=np.int64) for k in keyframes], frame_ids)
    additions = [np.asarray(frames[i], dtype=np.int64) for i in up_rows] + ranked
    additions = additions[:max_budget]
    # the rank at which each point first enters the map as keyframes are added in order
    if additions:
        ids = np.concatenate(additions)
        ranks = np.repeat(np.arange(len(additions)), [a.size for a in additions])
        order = np.lexsort((ranks, ids))
        ids, ranks = ids[order], ranks[order]
        first = np.r_[True, ids[1:] != ids[:-1]]
        universe, first_rank = ids[first], ranks[first]
    else:
        universe, first_rank = np.zeros(0, np.int64), np.zeros(0, np.int64)
    # per scored frame: the budget at which its min_shared-th point is in the map
    needed = np.full(len(frame_ids), np.iinfo(np.int64).max)
    for i, f in enumerate(frame_ids):
        at = np.searchsorted(universe, f)
        known = at < universe.size
        known[known] = universe[at[known]] == f[known]
        r = np.sort(first_rank[at[known]])
        if r.size >= min_shared:
            needed[i] = r[min_shared - 1] + 1      # keyframes the map must hold
    budgets = np.arange(max_budget + 1)
    return np.asarray((needed[None, :] <= budgets[:, None]).mean(axis=1), dtype=np.float64)


def _by_covisibility(keyframes: list[np.ndarray], frames: list[np.ndarray]) -> list[np.ndarray]:
    """``keyframes`` most covisible with ``frames`` first (Σ shared points; ties: newer
    first, as given later)."""
    if not keyframes:
        return []
    seen = np.unique(np.concatenate(frames)) if frames else np.zeros(0, np.int64)
    counts = np.zeros(len(seen), dtype=np.int64)
    for f in frames:
        counts[np.searchsorted(seen, np.unique(f))] += 1
    score = np.empty(len(keyframes))
    for j, k in enumerate(keyframes):
        at = np.searchsorted(seen, k)
        hit = at < seen.size
        hit[hit] = seen[at[hit]] == k[hit]
        score[j] = counts[at[hit]].sum()
    order = np.lexsort((-np.arange(len(keyframes)), -score))
    return [keyframes[j] for j in order]
