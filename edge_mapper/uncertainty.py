"""Pose estimation uncertainty of a keyframe map (paper eq. 6 and 8, DESIGN.md §2).

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
from dataclasses import dataclass

import numpy as np

#: u of a next-slot frame that shares no map point is +inf (it would lose tracking). RL and
#: the objective need a finite number: such a frame counts as u(G) + LOST_FRAME_PENALTY.
LOST_FRAME_PENALTY = 100.0
#: A Cholesky pivot (diag(R)²) below this share of the matrix's largest diagonal entry is a
#: rounding-level zero: the matrix is singular (a disconnected graph). For integer weights the
#: pivots of a connected graph are ratios of spanning-forest counts, far above this.
_PIVOT_RTOL = 1e-11


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
    if float((diag * diag).min()) <= _PIVOT_RTOL * max(1.0, float(np.diagonal(m).max())):
        return -math.inf
    return 2.0 * float(np.log(diag).sum())


def batched_logdet_spd(matrices: np.ndarray) -> np.ndarray:
    """logdet of a stack of SPD matrices (m, n, n); -inf where one is singular."""
    mats = np.asarray(matrices, dtype=np.float64)
    m, n = mats.shape[0], mats.shape[-1]
    if n == 0:
        return np.zeros(m)
    chol, ok = _batched_cholesky(mats)
    out = np.full(m, -math.inf)
    if ok.any():
        diag = np.diagonal(chol[ok], axis1=1, axis2=2)
        scale = np.maximum(1.0, np.diagonal(mats[ok], axis1=1, axis2=2).max(axis=1))
        good = (diag * diag).min(axis=1) > _PIVOT_RTOL * scale
        vals = np.full(diag.shape[0], -math.inf)
        vals[good] = 2.0 * np.log(diag[good]).sum(axis=1)
        out[ok] = vals
    return out


def _batched_cholesky(mats: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Cholesky of each matrix; numpy's batched call fails as a whole, so retry one by one."""
    try:
        return np.linalg.cholesky(mats), np.ones(mats.shape[0], dtype=bool)
    except np.linalg.LinAlgError:
        chol = np.zeros_like(mats)
        ok = np.zeros(mats.shape[0], dtype=bool)
        for i, mat in enumerate(mats):
            try:
                chol[i] = np.linalg.cholesky(mat)
                ok[i] = True
            except np.linalg.LinAlgError:
                pass
        return chol, ok


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
    return -6.0 * ld - (n - 1) * log_det_pi


def augmented_uncertainties(map_weights: np.ndarray, cand_weights: np.ndarray,
                            log_det_pi: float = 0.0) -> np.ndarray:
    """u(G ∪ {f}) for each candidate frame f (eq. 8's summand), all at once.

    ``cand_weights[i, j]`` is the weight between candidate i and map frame j. Grounding the
    *candidate* (allowed by Kirchhoff) turns L̂(G ∪ {f}) into L(G) + diag(b_f), so all
    candidates share L(G) and one batched Cholesky scores them. A candidate that shares no
    point with the map, or any candidate of a disconnected map, gets +inf.
    """
    w = np.asarray(map_weights, dtype=np.float64)
    b = np.atleast_2d(np.asarray(cand_weights, dtype=np.float64))
    n = w.shape[0]
    if n == 0:
        return np.full(b.shape[0], math.inf)
    u = np.full(b.shape[0], math.inf)
    # A frame sharing no point is lost without factorising anything; leaving it out also keeps
    # the batch free of singular matrices, so numpy's batched Cholesky does not fall back.
    live = np.flatnonzero(b.sum(axis=1) > 0)
    if live.size == 0:
        return u
    lap = laplacian(w)
    mats = np.broadcast_to(lap, (live.size, n, n)).copy()
    idx = np.arange(n)
    mats[:, idx, idx] += b[live]
    ld = batched_logdet_spd(mats)
    u[live] = np.where(np.isfinite(ld), -6.0 * ld - n * log_det_pi, math.inf)
    return u


@dataclass(frozen=True)
class SlotUncertainty:
    """υ_k over the next slot's frames, reported the two ways DESIGN.md §2 asks for."""

    mean_tracked: float        #: mean u(G ∪ {f}) over frames that share a point with the map
    lost_ratio: float          #: share of frames that share no point (u = +inf)
    objective: float           #: mean with lost frames counted as u(G) + LOST_FRAME_PENALTY

    @property
    def reward(self) -> float:
        """r_k = -υ_k on the finite objective (paper eq. 13 with the lost-frame penalty)."""
        return -self.objective


def next_slot_uncertainty(map_weights: np.ndarray, cand_weights: np.ndarray,
                          log_det_pi: float = 0.0,
                          lost_penalty: float = LOST_FRAME_PENALTY) -> SlotUncertainty:
    """υ_k of eq. (8) for the map G^e_{k+1} and the frames F_{k+1}, never letting inf leak."""
    u = augmented_uncertainties(map_weights, cand_weights, log_det_pi)
    if u.size == 0:
        raise ValueError("the next slot holds no frames")
    finite = np.isfinite(u)
    base = map_uncertainty(map_weights, log_det_pi)
    if not math.isfinite(base):
        # An empty or disconnected map: fall back to the penalty alone so the objective stays
        # finite and worse than any tracked frame of a connected map would make it.
        base = float(np.max(u[finite])) if finite.any() else 0.0
    lost_value = base + lost_penalty
    values = np.where(finite, u, lost_value)
    return SlotUncertainty(
        mean_tracked=float(u[finite].mean()) if finite.any() else math.nan,
        lost_ratio=float(1.0 - finite.mean()),
        objective=float(values.mean()),
    )


def theorem1_cardinalities(rate_mbps: float, alpha_mbit: float, d_req_s: float, vmax: int,
                           map_size: int, slot_size: int) -> tuple[int, int]:
    """(|U_k|, |C_k|) of paper Theorem 1, clamped to what the slot and the map hold.

    |U_k| = floor(d_k · D_req / α) (eq. 10), at most |F_k|. The paper prints
    |C_k| = V_max - |U_k| (eq. 11), but its own proof (eq. 12) keeps the map at V_max:
    |C_k| = |V_k| + |U_k| - V_max, never negative. We use eq. 12.
    """
    if not math.isfinite(rate_mbps) or rate_mbps < 0:
        raise ValueError(f"uplink rate must be finite and >= 0, got {rate_mbps}")
    if alpha_mbit <= 0 or d_req_s <= 0 or vmax < 1:
        raise ValueError("alpha, D_req must be > 0 and V_max >= 1")
    n_up = min(math.floor(rate_mbps * d_req_s / alpha_mbit + 1e-9), slot_size)
    n_up = min(n_up, vmax)
    n_evict = max(0, map_size + n_up - vmax)
    return n_up, n_evict
