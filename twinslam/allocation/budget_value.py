"""What a keyframe budget is worth to one device: its predicted tracked share as a function of
the budget, the curve the ``twin`` allocator splits V_total by
(:mod:`twinslam.allocation.allocators`).

Only what the edge knows when it decides: the device's map (each keyframe's point ids), the
frames of its last slot (their point ids; they stand for the next slot's frames, which the
device has not seen yet) and the uploads its rate twin expects next slot. Those uploads take
their place in the map whatever the budget (they are what the device moves on with), so a
budget of b keyframes keeps b − uploads of the old ones, the most covisible with the last
slot's frames first; value[b] is the share of those frames that share at least ``min_shared``
points with the kept old keyframes — the rule the device lives by
(:mod:`twinslam.slot_protocol.lost_frame_rule`). The curve is what the old map is worth: flat for a
device walking into new ground (its uploads carry it), rising for one that comes back to
places its map holds, and shifted right by a good uplink's uploads.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from twinslam.kernel_cache import njit
from twinslam.uncertainty.map_uncertainty import theorem1_uploads


def expected_uploads(state_probs: Sequence[float] | np.ndarray,
                     state_rates_mbps: Sequence[float] | np.ndarray,
                     alpha_mbit: float, d_req_s: float, slot_frames: int,
                     slot_s: float = 0.0) -> float:
    """E[|U_{k+1}|] under a predictive distribution over the rate states: Σ_s p(s)·⌊d_s D_req/α⌋
    (Theorem 1's count; ``slot_s`` > 0 with its progress rule), at most a slot's frames."""
    p = np.asarray(state_probs, dtype=np.float64)
    rates = np.asarray(state_rates_mbps, dtype=np.float64)
    if p.shape != rates.shape or p.size == 0:
        raise ValueError(f"{p.size} state probabilities for {rates.size} state rates")
    counts = np.array([theorem1_uploads(float(r), alpha_mbit, d_req_s, slot_frames, slot_s)
                       for r in rates], dtype=np.float64)
    return float(np.dot(p / p.sum(), counts))


#: frames of a slot scored at most, evenly spaced: a slot's 60 frames are highly redundant,
#: and sorting every one of their points costs ~5 ms a device
SCORED_FRAMES = 12


def budget_value(keyframes: Sequence[np.ndarray], frames: Sequence[np.ndarray],
                 uploads: float, min_shared: int, max_budget: int,
                 id_bound: int | None = None) -> np.ndarray:
    """value[b], b = 0 … ``max_budget``: the share of ``frames`` (point-id arrays) that share
    at least ``min_shared`` points with the b − ``round(uploads)`` keyframes of ``keyframes``
    (point-id arrays) most covisible with them (at most :data:`SCORED_FRAMES` frames, evenly
    spaced, are scored). Each array is a set: no id twice in one. Non-decreasing in b, at most
    len(keyframes) + uploads + 1 long (flat beyond); zeros without frames or keyframes.
    ``id_bound``: every id is in 0 … id_bound − 1 (a covisibility dataset's points), which
    saves renumbering them."""
    if min_shared < 1 or max_budget < 0:
        raise ValueError("min_shared must be >= 1 and max_budget >= 0")
    n_up = round(max(uploads, 0.0))
    out = np.zeros(min(max_budget, n_up + len(keyframes)) + 1)
    pick: list[int] = (np.unique(np.linspace(0, len(frames) - 1, min(len(frames), SCORED_FRAMES)
                                             ).round().astype(np.int64)).tolist()
                       if len(frames) else [])
    kept = max_budget - n_up
    if not pick or not keyframes or kept <= 0:
        return out
    key_ids, key_offsets = _flat([np.asarray(k, dtype=np.int64) for k in keyframes])
    frame_ids, frame_offsets = _flat([np.asarray(frames[i], dtype=np.int64) for i in pick])
    if id_bound is None:                       # any ids (track ids are negative): 0 … P − 1
        every, inverse = np.unique(np.concatenate([key_ids, frame_ids]), return_inverse=True)
        key_ids, frame_ids = inverse[:key_ids.size], inverse[key_ids.size:]
        id_bound = every.size
    needed = _keyframes_needed(key_ids, key_offsets, frame_ids, frame_offsets, int(id_bound),
                               int(min_shared), int(kept))
    budgets = np.arange(out.size)
    out[:] = ((needed[None, :] + n_up) <= budgets[:, None]).mean(axis=1)
    return out


def _flat(arrays: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Arrays as one concatenation and its offsets (CSR)."""
    offsets = np.zeros(len(arrays) + 1, dtype=np.int64)
    offsets[1:] = np.cumsum([a.size for a in arrays])
    return (np.concatenate(arrays) if arrays else np.zeros(0, np.int64)), offsets


@njit(cache=True)
def _keyframes_needed(key_ids: np.ndarray, key_offsets: np.ndarray, frame_ids: np.ndarray,
                      frame_offsets: np.ndarray, id_bound: int, min_shared: int,
                      kept: int) -> np.ndarray:  # pragma: no cover - compiled
    """Per frame, how many of the keyframes (most covisible with the frames first, ties: the
    newer first; at most ``kept``) the map must hold before ``min_shared`` of its points are
    in it; a huge number when never."""
    never = np.iinfo(np.int64).max // 2
    n_keys, n_frames = key_offsets.size - 1, frame_offsets.size - 1
    seen = np.zeros(id_bound, dtype=np.int64)          # frames observing each point
    for j in range(frame_ids.size):
        seen[frame_ids[j]] += 1
    score = np.zeros(n_keys)
    for k in range(n_keys):
        for j in range(key_offsets[k], key_offsets[k + 1]):
            score[k] += seen[key_ids[j]]
        score[k] = -score[k] * (n_keys + 1) - k        # by score, then the newer first
    order = np.argsort(score)[:kept]
    rank = np.full(id_bound, never, dtype=np.int64)    # the keyframe rank a point enters at
    for r in range(order.size):
        k = order[r]
        for j in range(key_offsets[k], key_offsets[k + 1]):
            if rank[key_ids[j]] == never:
                rank[key_ids[j]] = r
    needed = np.full(n_frames, never, dtype=np.int64)
    counts = np.zeros(order.size + 1, dtype=np.int64)
    for f in range(n_frames):
        counts[:] = 0
        for j in range(frame_offsets[f], frame_offsets[f + 1]):
            r = rank[frame_ids[j]]
            if r != never:
                counts[r] += 1
        total = 0
        for r in range(order.size):
            total += counts[r]
            if total >= min_shared:
                needed[f] = r + 1
                break
    return needed
