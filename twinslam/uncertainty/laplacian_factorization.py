"""A frame set's grounded Laplacian, factorised once and scored against many frames.

Every score here is a log weighted spanning-tree count τ (Kirchhoff: det of any reduced
Laplacian), the quantity u(G) = -6 log τ(G) - (|V|-1) logdet Π is made of. υ_k scores 60 frames
against one map and ADAPT's greedy scores every candidate in each of its rounds; both differ
from the map by one frame, so :class:`LaplacianFactorization` keeps C = A⁻¹ of the map's grounded
Laplacian A and answers each query from the few entries of C the frame touches
(``laplacian_kernels``). ADAPT's greedy (``greedy_kernels``) borders (add) or downdates
(remove) that inverse after each pick in O(n²k) instead of refactorising; the tests drive the
same kernels from Python against from-scratch counts (``tests/laplacian_reference.py``).

A disconnected set is grounded once per component (A stays positive definite); adding a frame
that touches every component is then still scored exactly, so a bridging frame is not mistaken
for a lost one.
"""

from __future__ import annotations

import math

import numpy as np

from twinslam.uncertainty import laplacian_kernels as kernels

#: Scores within this relative distance of the best count as tied (greedy picks the oldest).
TIE_RTOL = 1e-9
#: Headroom on the upper bounds (Hadamard for removals, Rayleigh for additions) against
#: rounding in the exact scores they are compared to.
BOUND_RTOL = 1e-12
#: A Cholesky pivot (diag(R)²) below this share of the matrix's largest diagonal entry is a
#: rounding-level zero: the matrix is singular (a disconnected graph). For integer weights the
#: pivots of a connected graph are ratios of spanning-forest counts, far above this.
PIVOT_RTOL = 1e-11


class LaplacianFactorization:
    """C = A⁻¹ and log det A for a symmetric weight matrix (frames in set order).

    Frame 0 of each component is grounded (for a connected set, the oldest frame — the map's
    anchor). ``log_tau`` is log τ(G) for a connected set and -inf otherwise.
    """

    def __init__(self, weights: np.ndarray) -> None:
        w = np.asarray(weights, dtype=np.float64)
        if w.shape[0] == 0:
            self.weights = np.zeros((0, 0))
            self.inverse = np.zeros((0, 0))
            self.pos = self.comp = np.zeros(0, dtype=np.int64)
            self.n_comp = 0
            self.log_det_a = 0.0
            return
        (self.weights, self.inverse, self.pos, self.comp, self.n_comp,
         self.log_det_a) = kernels.factorise(w, PIVOT_RTOL)
        if self.log_det_a == -math.inf:      # cannot happen for finite non-negative weights
            raise ValueError("grounded Laplacian is not positive definite; are the weights "
                             "finite and non-negative?")

    @property
    def n(self) -> int:
        return self.weights.shape[0]

    @property
    def connected(self) -> bool:
        return self.n_comp == 1

    @property
    def log_tau(self) -> float:
        """log of the weighted spanning-tree count; -inf when disconnected or empty."""
        return self.log_det_a if self.connected else -math.inf

    # -- queries ------------------------------------------------------------------------------

    def augmented_log_tau(self, cand: np.ndarray, rows: np.ndarray | None = None,
                          upper: np.ndarray | None = None) -> np.ndarray:
        """log τ(G ∪ {f}) for each row f of ``cand`` (weights to the set, in set order).

        With ``rows`` only those rows are scored (in that order). With ``upper`` — proven
        upper bounds on log(τ(G ∪ {f}) / τ(G)), indexed by row — only the rows that could be
        :func:`pick_best`'s pick are scored exactly; the others come back as -inf.
        """
        b = np.ascontiguousarray(np.atleast_2d(cand), dtype=np.float64)
        if rows is None:
            rows = np.arange(b.shape[0])
        if self.n == 0 or rows.size == 0:
            return np.full(rows.size, -math.inf)
        if b.shape[1] != self.n:
            raise ValueError(f"candidate weights have {b.shape[1]} columns, the set {self.n}")
        return kernels.augmented_log_taus(self.inverse, self.pos, self.comp, self.n_comp, b,
                                          rows, upper, self.log_det_a, TIE_RTOL, BOUND_RTOL,
                                          PIVOT_RTOL)


def tie_floor(best: float) -> float:
    """Lowest score that still ties with ``best``."""
    return best - TIE_RTOL * max(1.0, abs(best)) if math.isfinite(best) else best


def pick_best(values: np.ndarray) -> int:
    """Index of the largest value; near-ties (relative 1e-9) go to the lowest index (oldest
    frame), so that exact and incremental greedy agree despite rounding."""
    vals = values.tolist() if isinstance(values, np.ndarray) else list(values)
    best = max(vals)                  # a Python pass beats three numpy calls at this size
    if best == -math.inf:
        return 0
    floor = tie_floor(best)
    return next(i for i, v in enumerate(vals) if v >= floor)
