"""Pose estimation uncertainty of a keyframe map (paper eq. 6 and 8, docs/architecture.md §2).

The map is a weighted covisibility graph: w(f, f') = |M_f ∩ M_f'|. Its uncertainty is

    u(G) = -log det(L̂ ⊗ Π) = -6 logdet(L̂) - (|V| - 1) logdet(Π),

with L̂ the weighted Laplacian reduced by one grounded frame. By Kirchhoff's matrix-tree
theorem every principal cofactor of a Laplacian equals the weighted spanning-tree count, so the
choice of grounded frame does not change det(L̂); we ground the oldest frame of the map (index 0
of every weight matrix here). Determinants are never formed: logdet comes from a float64
Cholesky factor, and a factorisation that fails (or has a vanishing pivot) means the graph is
disconnected, reported as u = +inf.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from twinslam.uncertainty import laplacian_kernels as kernels
from twinslam.uncertainty.laplacian_factorization import PIVOT_RTOL, LaplacianFactorization

#: u of a lost next-slot frame (twinslam/slot_protocol/lost_frame_rule.py: too few shared map
#: points; in the paper, one that shares none). The paper's u is +inf there (the frame
#: cannot be tracked); a finite objective needs a number, and docs/architecture.md §2 scores such a
#: frame as a frame with no map at all: u = 0, worse than any tracked frame (with Π = I and integer
#: covisibility weights every tracked frame has u <= 0). The u(G) + 100 used before
#: made a lost frame cost ~4 % more than a tracked one at V_max 45: cheap enough for a policy
#: to lose a third of the next slot's frames and still rank first.
LOST_FRAME_UNCERTAINTY = 0.0


def laplacian(weights: np.ndarray) -> np.ndarray:
    """L = D - W of a symmetric, non-negative weight matrix with zero diagonal."""
    w = np.asarray(weights, dtype=np.float64)
    return np.diag(w.sum(axis=1)) - w


def reduced_laplacian(weights: np.ndarray) -> np.ndarray:
    """L̂: the Laplacian with the row and column of frame 0 (the anchor) removed."""
    return laplacian(weights)[1:, 1:]


def logdet_spd(matrix: np.ndarray) -> float:
    """log det of a symmetric positive definite matrix, or -inf if it is singular/indefinite."""
    m = np.asarray(matrix, dtype=np.float64)
    if m.shape[0] == 0:
        return 0.0
    try:
        chol = np.linalg.cholesky(m)
    except np.linalg.LinAlgError:
        return -math.inf
    diag = np.diagonal(chol)
    if float((diag * diag).min()) <= PIVOT_RTOL * max(1.0, float(np.diagonal(m).max())):
        return -math.inf
    return 2.0 * float(np.log(diag).sum())


def logdet_pi(pi: np.ndarray | None) -> float:
    """logdet(Π) of the 6x6 information parameter (identity, i.e. 0, by default)."""
    if pi is None:
        return 0.0
    p = np.asarray(pi, dtype=np.float64)
    if p.shape != (6, 6) or not np.allclose(p, p.T):
        raise ValueError(f"Π must be a symmetric 6x6 matrix, got shape {p.shape}")
    value = logdet_spd(p)
    if not math.isfinite(value):
        raise ValueError("Π must be positive definite")
    return value


def map_uncertainty(weights: np.ndarray, log_det_pi: float = 0.0) -> float:
    """u(G) for the map whose frames have pairwise weights ``weights`` (oldest frame first).

    An empty map is +inf (nothing can be tracked); a single frame is 0 (L̂ is 0x0).
    """
    n = np.asarray(weights).shape[0]
    if n == 0:
        return math.inf
    ld = logdet_spd(reduced_laplacian(weights))
    if ld == -math.inf:
        return math.inf
    return float(-6.0 * ld - (n - 1) * log_det_pi)


def augmented_uncertainties(map_weights: np.ndarray, cand_weights: np.ndarray,
                            log_det_pi: float = 0.0) -> np.ndarray:
    """u(G ∪ {f}) for each candidate frame f (eq. 8's summand), all at once.

    ``cand_weights[i, j]`` is the weight between candidate i and map frame j. One factorisation
    of the map serves every candidate
    (:class:`~twinslam.uncertainty.laplacian_factorization.LaplacianFactorization`). A candidate
    that shares no point with the map, or leaves G ∪ {f} disconnected, gets +inf.
    """
    return _augmented(LaplacianFactorization(map_weights), cand_weights, log_det_pi)


def _augmented(factor: LaplacianFactorization, cand_weights: np.ndarray, log_det_pi: float
               ) -> np.ndarray:
    log_tau = factor.augmented_log_tau(cand_weights)
    n = factor.n
    with np.errstate(invalid="ignore"):
        return np.where(np.isfinite(log_tau), -6.0 * log_tau - n * log_det_pi, math.inf)


@dataclass(frozen=True)
class SlotUncertainty:
    """υ_k over the next slot's frames, kept as sums so that every aggregate over slots, runs
    and seeds stays consistent: mean = (1 - lost share) · tracked mean for any pooling
    (docs/architecture.md §2, §9)."""

    tracked_sum: float         #: Σ u(G ∪ {f}) over the frames that share a point with the map
    n_tracked: int             #: frames that share a point with the map
    n_frames: int              #: frames of the next slot (tracked + lost)
    map_uncertainty: float = math.inf   #: u(G) of the map itself (+inf if disconnected)

    @property
    def n_lost(self) -> int:
        return self.n_frames - self.n_tracked

    @property
    def lost_share(self) -> float:
        """Share of the next slot's frames that are lost (too few shared map points)."""
        return self.n_lost / self.n_frames

    @property
    def tracked_uncertainty(self) -> float:
        """Mean u(G ∪ {f}) over the tracked frames only; NaN when every frame is lost."""
        return self.tracked_sum / self.n_tracked if self.n_tracked else math.nan

    @property
    def objective(self) -> float:
        """υ_k: the mean over every frame, a lost frame scoring LOST_FRAME_UNCERTAINTY (0)."""
        return (self.tracked_sum + self.n_lost * LOST_FRAME_UNCERTAINTY) / self.n_frames

    @property
    def reward(self) -> float:
        """r_k = -υ_k (paper eq. 13), the same υ every table reports."""
        return -self.objective


@dataclass(frozen=True)
class UncertaintyTally:
    """υ pooled over many slots (a run, or every run of a policy) by summing frames, so that
    a pooled mean, lost share and tracked mean obey the same identity as one slot's."""

    tracked_sum: float = 0.0
    n_tracked: int = 0
    n_frames: int = 0

    @classmethod
    def of(cls, parts: Iterable[SlotUncertainty | UncertaintyTally]) -> UncertaintyTally:
        """Every part's frames pooled into one tally."""
        total = cls()
        for part in parts:
            total = total.add(part)
        return total

    def add(self, part: SlotUncertainty | UncertaintyTally) -> UncertaintyTally:
        return UncertaintyTally(self.tracked_sum + part.tracked_sum,
                                self.n_tracked + part.n_tracked, self.n_frames + part.n_frames)

    @property
    def mean(self) -> float:
        """Mean υ over every frame, a lost frame scoring 0; NaN when nothing was tallied."""
        lost = (self.n_frames - self.n_tracked) * LOST_FRAME_UNCERTAINTY
        return (self.tracked_sum + lost) / self.n_frames if self.n_frames else math.nan

    @property
    def lost_share(self) -> float:
        return 1.0 - self.n_tracked / self.n_frames if self.n_frames else math.nan

    @property
    def tracked_uncertainty(self) -> float:
        return self.tracked_sum / self.n_tracked if self.n_tracked else math.nan


def next_slot_uncertainty(map_weights: np.ndarray, cand_weights: np.ndarray,
                          log_det_pi: float = 0.0, trackable: np.ndarray | None = None
                          ) -> SlotUncertainty:
    """υ_k of eq. (8) for the map G^e_{k+1} and the frames F_{k+1}, never letting inf leak;
    a frame ``trackable`` marks False counts as lost (:func:`slot_uncertainty_from_scores`).

    One kernel call (factorise + score every frame). The map's weights go to it contiguous:
    the planner passes the map's corner of a larger matrix (strided) and a map of its own
    may be whole (contiguous); numba compiles an overload a memory layout, the second one
    in the middle of a slot."""
    w = np.ascontiguousarray(map_weights, dtype=np.float64)
    b = np.ascontiguousarray(np.atleast_2d(cand_weights), dtype=np.float64)
    n = w.shape[0]
    if b.shape[0] == 0:
        raise ValueError("the next slot holds no frames")
    if n == 0:
        n_comp, log_det, log_tau = 0, -math.inf, np.full(b.shape[0], -math.inf)
    else:
        if b.shape[1] != n:
            raise ValueError(f"candidate weights have {b.shape[1]} columns, the map {n}")
        n_comp, log_det, log_tau = kernels.slot_scores(w, b, PIVOT_RTOL)
    return slot_uncertainty_from_scores(n, n_comp, log_det, log_tau, log_det_pi, trackable)


def slot_uncertainty_from_scores(n: int, n_comp: int, log_det: float, log_tau: np.ndarray,
                                 log_det_pi: float = 0.0, trackable: np.ndarray | None = None
                                 ) -> SlotUncertainty:
    """υ_k from a map of ``n`` frames with ``n_comp`` components and log det A = ``log_det``,
    and log τ(G ∪ {f}) of each next-slot frame (-inf: the frame shares no point). A frame
    ``trackable`` marks False (too few shared points: :mod:`twinslam.slot_protocol.lost_frame_rule`)
    is lost whatever its τ."""
    keep = log_tau > -math.inf
    if trackable is not None:
        keep &= trackable
    finite = log_tau[keep]
    n_tracked = int(finite.size)
    total = -6.0 * float(finite.sum()) - n_tracked * n * log_det_pi     # Σ u(G ∪ {f})
    map_u = -6.0 * log_det - (n - 1) * log_det_pi if n_comp == 1 else math.inf
    return SlotUncertainty(tracked_sum=total, n_tracked=n_tracked, n_frames=int(log_tau.size),
                           map_uncertainty=map_u)


def lost_frames(log_tau: np.ndarray, trackable: np.ndarray | None = None) -> np.ndarray:
    """Which next-slot frames :func:`slot_uncertainty_from_scores` scores as lost."""
    lost = ~(log_tau > -math.inf)
    return lost if trackable is None else lost | ~trackable


def theorem1_uploads(rate_mbps: float, alpha_mbit: float, d_req_s: float,
                     slot_size: int, slot_s: float = 0.0, waited_mbit: float = 0.0) -> int:
    """|U_k| of paper Theorem 1: floor(d_k · D_req / α) (eq. 10), at most the slot's |F_k| —
    the frames that fit the uplink within D_req. The one place the count is written: the
    cardinalities below, the twin allocator's expected uploads and the edge's grants use it.
    (The 1e-9 keeps a rate whose count is an integer, e.g. 40 Mbit/s · 0.5 s / 5 Mbit = 4,
    from losing a frame to float rounding.)

    ``slot_s`` > 0 adds the **progress rule** (DESIGN.md §7b): where D_req carries no frame
    (d_k < α / D_req: below 10 Mbit/s at Table I's α and D_req) but the uplink carries one
    within the slot's ``slot_s`` seconds, one frame goes, its deadline stretched to the slot's
    end — else an uplink under α / D_req uploads nothing, ever, and the edge never gets a map
    of the ground the device walks into. 0: Theorem 1 exactly (the paper's preset).

    ``waited_mbit``: what the uplink carried over the slots a device that needs a map has
    waited without an upload (:func:`waited_after`): a device in new ground or lost is served
    first, its deadline stretched over as many slots as a frame takes, so that an uplink
    under α a slot still brings it a keyframe every α / d_k seconds."""
    n = min(math.floor(rate_mbps * d_req_s / alpha_mbit + 1e-9), slot_size)
    if (n == 0 and slot_s > 0 and slot_size > 0
            and rate_mbps * slot_s + waited_mbit >= alpha_mbit - 1e-9):
        return 1
    return n


def waited_after(uploads: int, rate_mbps: float, slot_s: float, waited_mbit: float,
                 needs_map: bool) -> float:
    """:func:`theorem1_uploads`' ``waited_mbit`` for the next slot: what the uplink carried
    while a device that needs a map (:func:`needs_map`) went without an upload, this slot's
    ``rate_mbps`` · ``slot_s`` added. Nothing is carried after an upload, for a device its map
    still tracks (it loses nothing by waiting for a slot that carries a frame), or with the
    progress rule off (``slot_s`` 0, the paper's preset). The edge and the simulator both
    keep it this way, so both stretch the same deadlines."""
    if uploads > 0 or not needs_map or slot_s <= 0:
        return 0.0
    return waited_mbit + max(rate_mbps, 0.0) * slot_s


def needs_map(lost: Iterable[bool]) -> bool:
    """Whether a device needs keyframes of where it is now, from which of its slot's frames
    (capture order) are lost against the map (:mod:`twinslam.slot_protocol.lost_frame_rule`:
    too few shared map points, or the device could not track it): the newest one is — it
    walked into new ground or lost its map. The one test the edge and the simulator give
    priority by (:func:`waited_after`); a slot without frames needs nothing."""
    flags = list(lost)
    return bool(flags and flags[-1])


def theorem1_cardinalities(rate_mbps: float, alpha_mbit: float, d_req_s: float, vmax: int,
                           map_size: int, slot_size: int, slot_s: float = 0.0,
                           waited_mbit: float = 0.0) -> tuple[int, int]:
    """(|U_k|, |C_k|) of paper Theorem 1, clamped to what the slot and the map hold
    (``slot_s`` > 0: with :func:`theorem1_uploads`' progress rule, ``waited_mbit`` its
    priority for a device that needs a map).

    |U_k| = floor(d_k · D_req / α) (eq. 10), at most |F_k|. The paper prints
    |C_k| = V_max - |U_k| (eq. 11), but its own proof (eq. 12) keeps the map at V_max:
    |C_k| = |V_k| + |U_k| - V_max, never negative. We use eq. 12. V_max 0 (a device an edge
    has no keyframes for yet) uploads nothing and keeps nothing.
    """
    if not math.isfinite(rate_mbps) or rate_mbps < 0:
        raise ValueError(f"uplink rate must be finite and >= 0, got {rate_mbps}")
    if alpha_mbit <= 0 or d_req_s <= 0 or vmax < 0:
        raise ValueError("alpha, D_req must be > 0 and V_max >= 0")
    n_up = min(theorem1_uploads(rate_mbps, alpha_mbit, d_req_s, slot_size, slot_s,
                                waited_mbit), vmax)
    return n_up, theorem1_evictions(map_size, n_up, vmax)


def theorem1_evictions(map_size: int, uploads: int, vmax: int) -> int:
    """|C_k| = |V_k| + |U_k| - V_max, never negative (eq. 12): the evictions that keep a map
    of ``map_size`` keyframes within ``vmax`` once ``uploads`` come in."""
    return max(0, map_size + uploads - vmax)
