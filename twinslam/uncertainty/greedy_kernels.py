"""ADAPT's two greedy loops, each as one compiled call (numba).

The arithmetic of a greedy round — score the candidates, pick, border or downdate the inverse,
carry the bounds — lives in :mod:`twinslam.uncertainty.laplacian_kernels`; driven from Python, the
~16
rounds of one ADAPT decision paid more in call overhead and small-array handling than in
arithmetic. These loops make the same kernel calls in the same order as the step-by-step
reference the tests drive from Python (``tests/laplacian_reference.py``), so they pick exactly
what it picks; the tests compare both against a greedy that recomputes every determinant.
"""

from __future__ import annotations

import math

import numpy as np

from twinslam.kernel_cache import njit
from twinslam.uncertainty.laplacian_kernels import (
    augmented_log_taus,
    bordered,
    downdated,
    factorise,
    pruned_removal_log_ratios,
    raise_addition_bounds,
    subgraph_log_tau,
    tighten_addition_bounds,
)


@njit(cache=True)
def pick_best_index(values: np.ndarray, tie_rtol: float) -> int:
    """Index of the largest value, near-ties (relative ``tie_rtol``) to the lowest index; 0 if
    every value is -inf. The compiled twin of
    :func:`twinslam.uncertainty.laplacian_factorization.pick_best`."""
    best = -math.inf
    for x in values:
        best = max(best, x)
    if best == -math.inf:
        return 0
    floor = best - tie_rtol * max(1.0, abs(best))
    for i in range(values.size):
        if values[i] >= floor:
            return i
    return 0


@njit(cache=True)
def _connected_parts(n: int) -> tuple[np.ndarray, np.ndarray]:
    """pos and comp of a connected set with frame 0 grounded."""
    return np.arange(-1, n - 1), np.zeros(n, dtype=np.int64)


@njit(cache=True)
def greedy_additions(set_w: np.ndarray, cand_set_w: np.ndarray, cand_w: np.ndarray,
                     count: int, tie_rtol: float, bound_rtol: float, rtol: float) -> np.ndarray:
    """Candidate indices, in pick order, of ``count`` greedy additions (see
    :func:`twinslam.policies.rules.greedy_additions` for the rule)."""
    m = cand_set_w.shape[0]
    chosen = np.empty(count, dtype=np.int64)
    n_chosen = 0
    alive = np.ones(m, dtype=np.bool_)
    if set_w.shape[0] == 0:
        if count == 0:
            return chosen
        # An empty set: start from the candidate most connected to the others.
        degree = np.empty(m)
        for i in range(m):
            degree[i] = cand_w[i].sum()
        first = pick_best_index(degree, tie_rtol)
        chosen[0] = first
        n_chosen = 1
        alive[first] = False
        w, inv, pos, comp, n_comp, log_det = factorise(np.zeros((1, 1)), rtol)
        b = np.empty((m, 1))
        for i in range(m):
            b[i, 0] = cand_w[i, first]
    else:
        w, inv, pos, comp, n_comp, log_det = factorise(set_w, rtol)
        b = np.ascontiguousarray(cand_set_w).astype(np.float64)
    upper = np.full(m, math.inf)
    while n_chosen < count:
        rem = np.flatnonzero(alive)
        tighten_addition_bounds(inv, pos, comp, n_comp, b, rem, upper)
        scores = augmented_log_taus(inv, pos, comp, n_comp, b, rem, upper, log_det, tie_rtol,
                                    bound_rtol, rtol)
        if n_comp == 1:
            for i in range(rem.size):
                if scores[i] > -math.inf:
                    upper[rem[i]] = scores[i] - log_det
        best = pick_best_index(scores, tie_rtol)
        v = rem[best]
        score = scores[best]
        chosen[n_chosen] = v
        n_chosen += 1
        alive[v] = False
        n = w.shape[0]
        was_connected = n_comp == 1
        if was_connected and score > -math.inf:
            w, inv = bordered(w, inv, b[v], pos)
            pos, comp = _connected_parts(n + 1)
            n_comp, log_det = 1, score
        else:
            grown = np.zeros((n + 1, n + 1))
            grown[:n, :n] = w
            grown[n, :n] = b[v]
            grown[:n, n] = b[v]
            w, inv, pos, comp, n_comp, log_det = factorise(grown, rtol)
        to_v = np.empty(m)
        for i in range(m):
            to_v[i] = cand_w[i, v]
        if was_connected and n_comp == 1:
            raise_addition_bounds(inv, pos, b, to_v, np.flatnonzero(alive), upper)
        else:
            upper[:] = math.inf
        wider = np.empty((m, n + 1))
        wider[:, :n] = b
        wider[:, n] = to_v
        b = wider
    return chosen


@njit(cache=True)
def greedy_removals(set_w: np.ndarray, count: int, tie_rtol: float, bound_rtol: float,
                    rtol: float) -> np.ndarray:
    """Indices into the set, in removal order, of ``count`` greedy removals (see
    :func:`twinslam.policies.rules.greedy_removals` for the rule)."""
    w, inv, pos, comp, n_comp, log_det = factorise(np.ascontiguousarray(set_w), rtol)
    alive = np.arange(set_w.shape[0])
    removed = np.empty(count, dtype=np.int64)
    for r in range(count):
        n = w.shape[0]
        if n <= 2:
            i, score = 0, 0.0
        else:
            out = np.full(n, -math.inf)
            if n_comp == 1:
                ground = subgraph_log_tau(w, 1, rtol) - log_det
                pruned_removal_log_ratios(inv, pos, w, log_det, ground, tie_rtol, bound_rtol,
                                          rtol, out)
                out += log_det
            elif n_comp == 2:
                # Only dropping an isolated frame can reconnect a graph of two components.
                sizes = np.zeros(2, dtype=np.int64)
                for j in range(n):
                    sizes[comp[j]] += 1
                for j in range(n):
                    if sizes[comp[j]] == 1:
                        out[j] = log_det
            i = pick_best_index(out, tie_rtol)
            score = out[i]
        removed[r] = alive[i]
        alive = np.concatenate((alive[:i], alive[i + 1:]))
        if n_comp == 1 and score > -math.inf:
            w, inv = downdated(w, inv, pos, i)
            pos, comp = _connected_parts(n - 1)
            log_det = score
        else:
            keep = np.concatenate((np.arange(i), np.arange(i + 1, n)))
            smaller = np.empty((n - 1, n - 1))
            for a in range(n - 1):
                for c in range(n - 1):
                    smaller[a, c] = w[keep[a], keep[c]]
            w, inv, pos, comp, n_comp, log_det = factorise(smaller, rtol)
    return removed
