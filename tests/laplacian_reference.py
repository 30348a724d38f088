"""Reference greedy steps for the tests, not used by the project.

ADAPT's greedy runs as one compiled loop (``twinslam.uncertainty.greedy_kernels``). To check
its shortcuts, the tests need the same steps one at a time — removal scores, a pruned best
removal, a bordered or downdated factorization — and a greedy that recomputes every
determinant from scratch. The steps below call the very kernels the compiled loop calls, so
what they verify is the one implementation (``twinslam.uncertainty.naive_greedy`` is the
from-scratch greedy that shares nothing with it).
"""

from __future__ import annotations

import math

import numpy as np

from twinslam.uncertainty import laplacian_kernels as kernels
from twinslam.uncertainty.laplacian_factorization import (
    BOUND_RTOL,
    PIVOT_RTOL,
    TIE_RTOL,
    LaplacianFactorization,
    pick_best,
)


def _trivial_removals(f: LaplacianFactorization) -> np.ndarray | None:
    """Scores that need no factorization: tiny or disconnected sets; None otherwise."""
    n = f.n
    if n <= 2:
        return np.full(n, 0.0 if n == 2 else -math.inf)   # one frame left: τ = 1
    if f.connected:
        return None
    out = np.full(n, -math.inf)
    if f.n_comp == 2:          # only dropping an isolated frame can reconnect two components
        sizes = np.bincount(f.comp, minlength=2)
        out[sizes[f.comp] == 1] = f.log_det_a
    return out


def removal_log_tau(f: LaplacianFactorization) -> np.ndarray:
    """log τ(G \\ v) for every frame v (-inf where G \\ v is disconnected)."""
    out = _trivial_removals(f)
    if out is None:
        out = np.full(f.n, -math.inf)
        kernels.removal_log_ratios(f.inverse, f.pos, f.weights, PIVOT_RTOL, out)
        out[1:] += f.log_det_a
        out[0] = kernels.subgraph_log_tau(f.weights, 1, PIVOT_RTOL)
    return out


def best_removal(f: LaplacianFactorization) -> tuple[int, float]:
    """(v, log τ(G \\ v)) of the best removal through the pruned kernel the greedy uses."""
    out = _trivial_removals(f)
    if out is None:
        ratios = np.empty(f.n)
        ground = kernels.subgraph_log_tau(f.weights, 1, PIVOT_RTOL) - f.log_det_a
        kernels.pruned_removal_log_ratios(f.inverse, f.pos, f.weights, f.log_det_a, ground,
                                          TIE_RTOL, BOUND_RTOL, PIVOT_RTOL, ratios)
        out = ratios + f.log_det_a
    i = pick_best(out)
    return i, float(out[i])


def _from_parts(weights: np.ndarray, inverse: np.ndarray, log_det: float
                ) -> LaplacianFactorization:
    obj = LaplacianFactorization.__new__(LaplacianFactorization)
    obj.weights = weights
    obj.pos = np.arange(-1, weights.shape[0] - 1)
    obj.comp = np.zeros(weights.shape[0], dtype=np.int64)
    obj.n_comp = 1
    obj.inverse = np.ascontiguousarray(inverse)
    obj.log_det_a = log_det
    return obj


def with_frame(f: LaplacianFactorization, cand_row: np.ndarray,
               log_tau_after: float | None = None) -> LaplacianFactorization:
    """G ∪ {f} with f appended last: bordered when connected, refactorized otherwise."""
    b = np.ascontiguousarray(cand_row, dtype=np.float64)
    if log_tau_after is None:
        log_tau_after = float(f.augmented_log_tau(b[None, :])[0])
    if not f.connected or not math.isfinite(log_tau_after):
        n = f.n
        w = np.zeros((n + 1, n + 1))
        w[:n, :n] = f.weights
        w[n, :n] = w[:n, n] = b
        return LaplacianFactorization(w)
    w, inv = kernels.bordered(f.weights, f.inverse, b, f.pos)
    return _from_parts(w, inv, log_tau_after)


def without_frame(f: LaplacianFactorization, v: int, log_tau_after: float
                  ) -> LaplacianFactorization:
    """G \\ {v}: downdated when G and G \\ v are connected, refactorized otherwise."""
    if not f.connected or not math.isfinite(log_tau_after):
        return LaplacianFactorization(np.delete(np.delete(f.weights, v, axis=0), v, axis=1))
    w, inv = kernels.downdated(f.weights, f.inverse, f.pos, v)
    return _from_parts(w, inv, log_tau_after)
