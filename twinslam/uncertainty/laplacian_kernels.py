"""Compiled inner loops of the spanning-tree scores (numba; see
twinslam/uncertainty/laplacian_factorization.py).

Each candidate frame touches only the few map frames it shares points with (k of them, ~15 of
45 on the room model), so its score is a k×k (or smaller) factorisation against the shared
inverse C of the map's grounded Laplacian. numpy's batched LAPACK pays ~1 µs of call overhead
per small matrix and cannot skip the zero weights; these loops do exactly the k³/6 work.

All matrices are float64. A Cholesky pivot below ``rtol · max(1, largest diagonal entry)`` is a
rounding-level zero and reports a singular matrix (-inf), the same rule as
:func:`twinslam.uncertainty.map_uncertainty.logdet_spd`.
"""

from __future__ import annotations

import math

import numpy as np

from twinslam.kernel_cache import njit

#: Let LLVM reorder the dot products in the factorisations (SIMD); no flag that assumes away
#: inf or NaN, since -inf is how a singular matrix is reported.
_FAST = {"reassoc", "contract"}


@njit(cache=True, fastmath=_FAST)
def cholesky_logdet(m: np.ndarray, k: int, rtol: float) -> float:
    """In-place lower Cholesky of ``m[:k, :k]`` (only the lower triangle is read); returns
    logdet, or -inf if not SPD."""
    scale = 1.0
    for j in range(k):
        scale = max(scale, m[j, j])
    logdet = 0.0
    prod = 1.0                            # product of pivots, folded into logdet now and then
    for j in range(k):
        s = m[j, j]
        for p in range(j):
            s -= m[j, p] * m[j, p]
        if s <= rtol * scale:
            return -math.inf
        ljj = math.sqrt(s)
        m[j, j] = ljj
        r = 1.0 / ljj                      # one division per column, not one per entry
        prod *= s
        if prod < 1e-150 or prod > 1e150:
            logdet += math.log(prod)
            prod = 1.0
        for i in range(j + 1, k):
            t = m[i, j]
            for p in range(j):
                t -= m[i, p] * m[j, p]
            m[i, j] = t * r
    return logdet + math.log(prod)


@njit(cache=True, fastmath=_FAST)
def _augmented_one(inv: np.ndarray, pos: np.ndarray, comp: np.ndarray, n_comp: int,
                   cand: np.ndarray, rtol: float, s_idx: np.ndarray, s_comp: np.ndarray,
                   d: np.ndarray, b_ground: np.ndarray, touched: np.ndarray, m: np.ndarray,
                   z: np.ndarray, t: np.ndarray) -> float:
    """log(τ(G ∪ {f}) / τ_A(G)) for one candidate f with weights ``cand`` to G; -inf if
    G ∪ {f} is disconnected.

    τ_A(G) is det A, A the Laplacian of G with one grounded frame per component removed
    (``pos[j]`` = row of frame j in A, -1 for a grounded frame; ``comp[j]`` its component) and
    ``inv`` = A⁻¹. Grounding f itself, τ(G ∪ {f}) = det(L(G) + diag(b)), and with S the
    non-grounded frames f touches (weights d), K = inv[S, S] and P the S×component indicator:

        det(L + diag b) / det A = Πd · det(K + D⁻¹) · det(diag(b_grounds) + Pᵀ (K + D⁻¹)⁻¹ P)

    (Schur complement on the grounded rows, then the matrix determinant lemma). Every term is
    a sum of positives, so nothing cancels; a component f does not touch makes the last
    matrix singular, which is decided combinatorially instead.
    """
    n = cand.shape[0]
    b_ground[:] = 0.0
    touched[:] = False
    k = 0
    log_d = 0.0
    prod_d = 1.0
    for j in range(n):
        w = cand[j]
        if w > 0.0:
            c = comp[j]
            touched[c] = True
            if pos[j] < 0:
                b_ground[c] = w
            else:
                s_idx[k] = pos[j]
                s_comp[k] = c
                d[k] = w
                prod_d *= w
                if prod_d > 1e150:
                    log_d += math.log(prod_d)
                    prod_d = 1.0
                k += 1
    for c in range(n_comp):
        if not touched[c]:
            return -math.inf
    for a in range(k):
        ia = s_idx[a]
        for b in range(a):
            m[a, b] = inv[ia, s_idx[b]]
        m[a, a] = inv[ia, ia] + 1.0 / d[a]
    ld_m = cholesky_logdet(m, k, rtol)
    if ld_m == -math.inf:
        return -math.inf
    # Pᵀ M⁻¹ P = ZᵀZ with Z = L⁻¹P: one forward substitution, no back substitution
    for a in range(k):
        for c in range(n_comp):
            zc = 1.0 if s_comp[a] == c else 0.0
            for q in range(a):
                zc -= m[a, q] * z[q, c]
            z[a, c] = zc / m[a, a]
    for c1 in range(n_comp):
        for c2 in range(c1 + 1):
            acc = 0.0
            for a in range(k):
                acc += z[a, c1] * z[a, c2]
            t[c1, c2] = acc
        t[c1, c1] += b_ground[c1]
    ld_t = cholesky_logdet(t, n_comp, rtol)
    return log_d + math.log(prod_d) + ld_m + ld_t


@njit(cache=True, fastmath=_FAST)
def augmented_log_taus(inv: np.ndarray, pos: np.ndarray, comp: np.ndarray, n_comp: int,
                       cand: np.ndarray, rows: np.ndarray, upper: np.ndarray | None,
                       log_det: float, tie_rtol: float, bound_rtol: float,
                       rtol: float) -> np.ndarray:
    """``log_det`` + :func:`_augmented_one` for the candidate rows ``rows`` of ``cand``.

    ``upper[f]`` (optional) bounds candidate f's ratio from above (+inf: unknown). Candidates
    are scored in order of decreasing bound, and scoring stops once no remaining bound can
    reach the best score ``log_det + ratio`` within its tie tolerance; the rest are left at
    -inf, as no greedy pick can be among them. Without bounds every row is scored.
    """
    out = np.empty(rows.size)
    n = cand.shape[1]
    s_idx = np.empty(n, dtype=np.int64)
    s_comp = np.empty(n, dtype=np.int64)
    d = np.empty(n)
    b_ground = np.empty(n_comp)
    touched = np.empty(n_comp, dtype=np.bool_)
    m = np.empty((n, n))
    z = np.empty((n, n_comp))
    t = np.empty((n_comp, n_comp))
    if upper is None:
        for i in range(rows.size):
            out[i] = log_det + _augmented_one(inv, pos, comp, n_comp, cand[rows[i]], rtol,
                                              s_idx, s_comp, d, b_ground, touched, m, z, t)
        return out
    bounds = np.empty(rows.size)
    for i in range(rows.size):
        out[i] = -math.inf
        bounds[i] = upper[rows[i]]
    best = -math.inf
    for i in np.argsort(-bounds, kind="mergesort"):
        if bounds[i] == -math.inf:          # known not to connect, and so are all after it
            break
        top = log_det + bounds[i]
        if best > -math.inf and top < math.inf:
            score = log_det + best
            if top + bound_rtol * max(1.0, abs(top)) < score - tie_rtol * max(1.0, abs(score)):
                break
        ratio = _augmented_one(inv, pos, comp, n_comp, cand[rows[i]], rtol, s_idx, s_comp,
                               d, b_ground, touched, m, z, t)
        out[i] = log_det + ratio
        best = max(best, ratio)
    return out


@njit(cache=True, fastmath=_FAST)
def _removal_support(v: int, pos: np.ndarray, weights: np.ndarray, s_idx: np.ndarray,
                     d: np.ndarray) -> int:
    """v's non-grounded neighbours (rows of A) into ``s_idx`` and their weights into ``d``."""
    k = 0
    for j in range(weights.shape[0]):
        w = weights[v, j]
        if j != v and w > 0.0 and pos[j] >= 0:
            s_idx[k] = pos[j]
            d[k] = w
            k += 1
    return k


@njit(cache=True, fastmath=_FAST)
def _removal_bound(v: int, inv: np.ndarray, pos: np.ndarray, weights: np.ndarray,
                   s_idx: np.ndarray, d: np.ndarray) -> float:
    """Hadamard bound on log(τ(G \\ v) / τ(G)) in O(k): det(D⁻¹ - K') ≤ Π (1/d_a - K'_aa) for
    the positive definite matrix of :func:`_removal_log_ratio`, so the ratio is at most
    C_vv · Π (1 - d_a K'_aa)."""
    p = pos[v]
    cvv = inv[p, p]
    k = _removal_support(v, pos, weights, s_idx, d)
    log_bound = math.log(cvv)
    prod = 1.0
    for a in range(k):
        ia = s_idx[a]
        slack = 1.0 - d[a] * (inv[ia, ia] - inv[ia, p] * inv[ia, p] / cvv)
        if slack <= 0.0:
            return -math.inf
        prod *= slack
        if prod < 1e-200:                 # keep the running product away from underflow
            log_bound += math.log(prod)
            prod = 1.0
    return log_bound + math.log(prod)


@njit(cache=True, fastmath=_FAST)
def _removal_log_ratio(v: int, inv: np.ndarray, pos: np.ndarray, weights: np.ndarray,
                       rtol: float, s_idx: np.ndarray, d: np.ndarray, m: np.ndarray,
                       u: np.ndarray) -> float:
    """log(τ(G \\ v) / τ(G)) for a non-grounded frame v of a *connected* G; -inf where
    removing v disconnects G.

    With A the grounded Laplacian and C = A⁻¹, deleting v's row and column gives det C_vv·det A
    and (A_{-v})⁻¹ = C - C_{:v} C_{v:} / C_vv; taking v's weights d off its neighbours S is the
    downdate det(A_{-v} - D) = det A_{-v} · Πd · det(D⁻¹ - K'), K' = (A_{-v})⁻¹[S, S]. That last
    matrix is positive definite exactly when G \\ v stays connected.
    """
    p = pos[v]
    cvv = inv[p, p]
    k = _removal_support(v, pos, weights, s_idx, d)
    sum_log_d = 0.0
    for a in range(k):
        sum_log_d += math.log(d[a])
        u[a] = inv[s_idx[a], p]
    for a in range(k):
        ia = s_idx[a]
        ua = u[a] / cvv
        for b in range(a + 1):
            m[a, b] = ua * u[b] - inv[ia, s_idx[b]]
        m[a, a] += 1.0 / d[a]
    ld = cholesky_logdet(m, k, rtol)
    return -math.inf if ld == -math.inf else math.log(cvv) + sum_log_d + ld


@njit(cache=True, fastmath=_FAST)
def removal_log_ratios(inv: np.ndarray, pos: np.ndarray, weights: np.ndarray, rtol: float,
                       out: np.ndarray) -> None:
    """:func:`_removal_log_ratio` of every non-grounded frame into ``out`` (all exact)."""
    n = weights.shape[0]
    s_idx = np.empty(n, dtype=np.int64)
    d = np.empty(n)
    m = np.empty((n, n))
    u = np.empty(n)
    for v in range(n):
        if pos[v] >= 0:
            out[v] = _removal_log_ratio(v, inv, pos, weights, rtol, s_idx, d, m, u)


@njit(cache=True, fastmath=_FAST)
def pruned_removal_log_ratios(inv: np.ndarray, pos: np.ndarray, weights: np.ndarray,
                              log_det: float, ground_ratio: float, tie_rtol: float,
                              slack: float, rtol: float, out: np.ndarray) -> None:
    """Removal ratios of a connected set with frame 0 grounded, exact wherever the greedy
    pick could be and -inf where a bound rules a frame out. The pick is the largest score
    ``log_det + ratio``, near-ties within ``tie_rtol`` (relative to the score) going to the
    oldest frame; bounds get ``slack`` (relative) of headroom for rounding. ``out[0]`` =
    ``ground_ratio``.

    Frames are tried in order of decreasing Hadamard bound; once the best exact score's tie
    floor exceeds the next bound, no later frame can win or tie.
    """
    n = weights.shape[0]
    s_idx = np.empty(n, dtype=np.int64)
    d = np.empty(n)
    m = np.empty((n, n))
    u = np.empty(n)
    bound = np.empty(n - 1)
    for v in range(1, n):
        bound[v - 1] = _removal_bound(v, inv, pos, weights, s_idx, d)
        out[v] = -math.inf
    out[0] = ground_ratio
    best = ground_ratio
    for i in np.argsort(-bound, kind="mergesort"):
        if best > -math.inf:
            score = log_det + best
            top = log_det + bound[i]
            if top + slack * max(1.0, abs(top)) < score - tie_rtol * max(1.0, abs(score)):
                break
        v = i + 1
        out[v] = _removal_log_ratio(v, inv, pos, weights, rtol, s_idx, d, m, u)
        best = max(best, out[v])


@njit(cache=True, fastmath=_FAST)
def subgraph_log_tau(weights: np.ndarray, first: int, rtol: float) -> float:
    """log τ of the frames ``first..n-1`` alone (frame ``first`` grounded); -inf if they are
    disconnected. Used for the removal of a connected set's grounded frame."""
    n = weights.shape[0]
    k = n - first - 1
    a = np.empty((max(k, 0), max(k, 0)))
    for i in range(k):
        r = first + 1 + i
        deg = 0.0
        for j in range(first, n):
            deg += weights[r, j]
        for j in range(k):
            a[i, j] = -weights[r, first + 1 + j]
        a[i, i] = deg
    return cholesky_logdet(a, k, rtol)


@njit(cache=True, fastmath=_FAST)
def grounded_inverse(weights: np.ndarray, keep: np.ndarray, rtol: float,
                     inv: np.ndarray) -> float:
    """A⁻¹ into ``inv`` and log det A, A the Laplacian of ``weights`` restricted to the frames
    ``keep`` (the non-grounded ones); -inf (``inv`` undefined) if A is singular.

    One pass instead of Laplacian + Cholesky + potri through numpy: at n ≈ 45 each of those
    calls costs more in dispatch than in arithmetic, and this runs once per slot.
    """
    n = weights.shape[0]
    k = keep.shape[0]
    a = np.empty((k, k))
    for i in range(k):
        deg = 0.0
        for j in range(n):
            deg += weights[keep[i], j]
        for j in range(k):
            a[i, j] = -weights[keep[i], keep[j]]
        a[i, i] = deg
    logdet = cholesky_logdet(a, k, rtol)
    if logdet == -math.inf:
        return logdet
    # X = L⁻¹ row by row (X[i] = (e_i - Σ_p L[i, p] X[p]) / L[i, i]), contiguous row updates
    x = np.zeros((k, k))
    for i in range(k):
        for p in range(i):
            lip = a[i, p]
            for j in range(p + 1):
                x[i, j] -= lip * x[p, j]
        x[i, i] += 1.0
        r = 1.0 / a[i, i]
        for j in range(i + 1):
            x[i, j] *= r
    # A⁻¹ = Xᵀ X as a sum of outer products of X's rows (lower triangle, then mirrored)
    for i in range(k):
        for j in range(k):
            inv[i, j] = 0.0
    for p in range(k):
        for i in range(p + 1):
            xpi = x[p, i]
            for j in range(i + 1):
                inv[i, j] += xpi * x[p, j]
    for i in range(k):
        for j in range(i):
            inv[j, i] = inv[i, j]
    return logdet


@njit(cache=True)
def components(weights: np.ndarray, labels: np.ndarray) -> int:
    """Connected components of the graph w > 0 into ``labels``, numbered in order of their
    first (oldest) frame; returns how many. Breadth-first on the dense matrix: n ≤ ~100."""
    n = weights.shape[0]
    labels[:] = -1
    queue = np.empty(n, dtype=np.int64)
    count = 0
    for root in range(n):
        if labels[root] >= 0:
            continue
        labels[root] = count
        head, tail = 0, 1
        queue[0] = root
        while head < tail:
            i = queue[head]
            head += 1
            for j in range(n):
                if labels[j] < 0 and weights[i, j] > 0.0:
                    labels[j] = count
                    queue[tail] = j
                    tail += 1
        count += 1
    return count


@njit(cache=True, fastmath=_FAST)
def forward_solve(chol: np.ndarray, k: int, rhs: np.ndarray, ncols: int) -> None:
    """Solve L X = B in place for ``rhs[:k, :ncols]``, L in ``chol[:k, :k]``, by rows."""
    for i in range(k):
        for p in range(i):
            lip = chol[i, p]
            for c in range(ncols):
                rhs[i, c] -= lip * rhs[p, c]
        r = 1.0 / chol[i, i]
        for c in range(ncols):
            rhs[i, c] *= r


@njit(cache=True, fastmath=_FAST)
def bordered(weights: np.ndarray, inv: np.ndarray, cand: np.ndarray,
             pos: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Weights and A'⁻¹ of a connected set grown by frame f (weights ``cand``, appended last).

    A' = [[A + D, -b], [-bᵀ, Σb]]. With L Lᵀ = K + D⁻¹ on f's support S, W = L⁻¹ C[S, :] and
    z = L⁻¹ 1: (A + D)⁻¹ = C - WᵀW (Woodbury), h = (A + D)⁻¹ b = Wᵀz and the Schur complement
    σ = b_ground + zᵀz (no cancellation), so A'⁻¹ = [[C - WᵀW + hhᵀ/σ, h/σ], [hᵀ/σ, 1/σ]].
    """
    m = inv.shape[0]
    n = cand.shape[0]
    w_new = np.empty((n + 1, n + 1))
    w_new[:n, :n] = weights
    for j in range(n):
        w_new[n, j] = cand[j]
        w_new[j, n] = cand[j]
    w_new[n, n] = 0.0
    s_idx = np.empty(n, dtype=np.int64)
    d = np.empty(n)
    b_ground = 0.0
    k = 0
    for j in range(n):
        w = cand[j]
        if w > 0.0:
            if pos[j] < 0:
                b_ground += w
            else:
                s_idx[k] = pos[j]
                d[k] = w
                k += 1
    mat = np.empty((k, k))
    for a in range(k):
        for b in range(a + 1):
            mat[a, b] = inv[s_idx[a], s_idx[b]]
        mat[a, a] += 1.0 / d[a]
    cholesky_logdet(mat, k, 0.0)
    y = np.empty((k, m + 1))               # columns :m become W, column m becomes z
    for a in range(k):
        for c in range(m):
            y[a, c] = inv[s_idx[a], c]
        y[a, m] = 1.0
    forward_solve(mat, k, y, m + 1)
    sigma = b_ground
    for a in range(k):
        sigma += y[a, m] * y[a, m]
    wz = np.ascontiguousarray(y[:, :m])
    h = np.zeros(m)
    for a in range(k):
        for c in range(m):
            h[c] += wz[a, c] * y[a, m]
    out = np.empty((m + 1, m + 1))
    out[:m, :m] = inv - wz.T @ wz + np.outer(h, h) / sigma    # BLAS for the O(m²k) part
    for r in range(m):
        out[r, m] = h[r] / sigma
        out[m, r] = h[r] / sigma
    out[m, m] = 1.0 / sigma
    return w_new, out


@njit(cache=True, fastmath=_FAST)
def downdated(weights: np.ndarray, inv: np.ndarray, pos: np.ndarray,
              v: int) -> tuple[np.ndarray, np.ndarray]:
    """Weights and A⁻¹ when frame v leaves a connected set that stays connected.

    For a non-grounded v, C' = C - C[:, p] C[p, :] / C_pp drops v's row and column; taking v's
    weights D off its neighbours S is then the Woodbury update C' + WᵀW, L Lᵀ = D⁻¹ - C'[S, S]
    and W = L⁻¹ C'[S, :]. When v is the ground (frame 0), frame 1 becomes the ground: the same
    two steps drop frame 1's row and take frame 0's weights off, and A's rows keep their order.
    """
    n = weights.shape[0]
    w_new = np.empty((n - 1, n - 1))
    for i in range(n - 1):
        si = i if i < v else i + 1
        for j in range(n - 1):
            w_new[i, j] = weights[si, j if j < v else j + 1]
    m = inv.shape[0]
    drop = v if pos[v] >= 0 else 1
    p = pos[drop]
    cpp = inv[p, p]
    keep = np.empty(m - 1, dtype=np.int64)
    q = 0
    for r in range(m):
        if r != p:
            keep[q] = r
            q += 1
    cm = np.empty((m - 1, m - 1))
    for r in range(m - 1):
        f = inv[keep[r], p] / cpp
        for c in range(m - 1):
            cm[r, c] = inv[keep[r], keep[c]] - f * inv[p, keep[c]]
    s_idx = np.empty(n, dtype=np.int64)
    d = np.empty(n)
    k = 0
    for j in range(n):
        if j != v and j != drop and weights[v, j] > 0.0 and pos[j] >= 0:
            s_idx[k] = pos[j] if pos[j] < p else pos[j] - 1
            d[k] = weights[v, j]
            k += 1
    mat = np.empty((k, k))
    for a in range(k):
        for b in range(a + 1):
            mat[a, b] = -cm[s_idx[a], s_idx[b]]
        mat[a, a] += 1.0 / d[a]
    cholesky_logdet(mat, k, 0.0)
    wz = np.empty((k, m - 1))
    for a in range(k):
        for c in range(m - 1):
            wz[a, c] = cm[s_idx[a], c]
    forward_solve(mat, k, wz, m - 1)
    return w_new, cm + wz.T @ wz             # BLAS for the O(m²k) part


@njit(cache=True, fastmath=_FAST)
def raise_addition_bounds(inv: np.ndarray, pos: np.ndarray, cand: np.ndarray,
                          to_new: np.ndarray, rows: np.ndarray, upper: np.ndarray) -> None:
    """Carry upper bounds on log(τ(S ∪ {f}) / τ(S)) over to the set S' = S ∪ {v}.

    ``inv``/``pos`` describe the connected S' (v last), ``cand[f]`` holds f's weights to S and
    ``to_new[f]`` its weight to v. Adding f's edges one at a time, each edge multiplies τ by
    1 + w·R, R the effective resistance it bridges. In S' every resistance is at most what it
    was in S (Rayleigh monotonicity), so the edges to S contribute at most the old ratio, and
    the edge to v at most 1 + w_fv · min_j (1/w_fj + R_S'(j, v)) (a path through neighbour j).
    A frame with no edge to S but one to v is a leaf of v: its ratio is exactly w_fv.
    """
    n_old = cand.shape[1]
    pv = pos[n_old]
    cvv = inv[pv, pv]
    for f in rows:
        w_fv = to_new[f]
        if w_fv <= 0.0:
            continue
        if upper[f] == -math.inf:
            upper[f] = math.log(w_fv)
            continue
        r_min = math.inf
        for j in range(n_old):
            w = cand[f, j]
            if w > 0.0:
                pj = pos[j]
                r = cvv if pj < 0 else inv[pj, pj] + cvv - 2.0 * inv[pj, pv]
                r_min = min(r_min, 1.0 / w + r)
        upper[f] += math.log1p(w_fv * r_min)


@njit(cache=True, fastmath=_FAST)
def tighten_addition_bounds(inv: np.ndarray, pos: np.ndarray, comp: np.ndarray, n_comp: int,
                            cand: np.ndarray, rows: np.ndarray, upper: np.ndarray) -> None:
    """upper[f] = min(upper[f], Hadamard bound on f's :func:`_augmented_one` ratio), O(n) each.

    With M = K + D⁻¹ on f's support: Πd·det M = det(I + D^½ K D^½) ≤ Π(1 + d_i C_ii)
    (Hadamard, the matrix being positive definite), and M ⪰ D⁻¹ gives Pᵀ M⁻¹ P ⪯ Pᵀ D P, so the
    last determinant is at most Π_c (b_ground,c + Σ_{i∈c} d_i). An untouched component gives
    -inf, as the exact score does. This lets the first greedy round skip most candidates,
    which no carried bound can do.
    """
    n = cand.shape[1]
    per_comp = np.empty(n_comp)
    for f in rows:
        per_comp[:] = 0.0
        bound = 0.0
        for j in range(n):
            w = cand[f, j]
            if w > 0.0:
                per_comp[comp[j]] += w
                pj = pos[j]
                if pj >= 0:
                    bound += math.log1p(w * inv[pj, pj])
        for c in range(n_comp):
            bound = bound + math.log(per_comp[c]) if per_comp[c] > 0.0 else -math.inf
        upper[f] = min(upper[f], bound)


@njit(cache=True)
def factorise(weights: np.ndarray, rtol: float
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, int, float]:
    """Everything a :class:`~twinslam.uncertainty.laplacian_factorization.
    LaplacianFactorization` holds, in one call:
    (weights with a zero diagonal, A⁻¹, pos, comp, number of components, log det A).

    Components first (a breadth-first pass costs far less than a failed factorisation), then
    the first frame of every component is grounded and A factorised once.
    """
    n = weights.shape[0]
    w = np.empty((n, n))
    for i in range(n):
        for j in range(n):
            w[i, j] = 0.0 if i == j else weights[i, j]
    comp = np.empty(n, dtype=np.int64)
    n_comp = components(w, comp)
    pos = np.empty(n, dtype=np.int64)
    keep = np.empty(n - n_comp, dtype=np.int64)
    seen = -1
    q = 0
    for i in range(n):
        if comp[i] > seen:                  # first frame of a component: its ground
            pos[i] = -1
            seen = comp[i]
        else:
            pos[i] = q
            keep[q] = i
            q += 1
    inv = np.empty((q, q))
    log_det = grounded_inverse(w, keep, rtol, inv)
    return w, inv, pos, comp, n_comp, log_det


@njit(cache=True)
def slot_scores(weights: np.ndarray, cand: np.ndarray, rtol: float
                ) -> tuple[int, float, np.ndarray]:
    """(components, log det A, log τ(G ∪ {f}) per candidate row) in one call: the simulator
    scores every slot this way, and at ~45 frames the Python round trips of a
    :class:`~twinslam.uncertainty.laplacian_factorization.LaplacianFactorization` cost as much
    as the arithmetic."""
    _, _, _, n_comp, log_det, log_tau = factored_slot_scores(weights, cand, rtol)
    return n_comp, log_det, log_tau


@njit(cache=True)
def factored_slot_scores(weights: np.ndarray, cand: np.ndarray, rtol: float
                         ) -> tuple[np.ndarray, np.ndarray, np.ndarray, int, float, np.ndarray]:
    """:func:`slot_scores` that also returns the factorisation it scored against: (A⁻¹, pos,
    comp, components, log det A, log τ(G ∪ {f}) per candidate row). The simulator scores the
    next slot's first frames against this same map (the update reaches the device late), so
    it keeps the factorisation for :func:`augmented_log_taus` instead of factorising twice."""
    _, inv, pos, comp, n_comp, log_det = factorise(weights, rtol)
    rows = np.arange(cand.shape[0])
    return inv, pos, comp, n_comp, log_det, augmented_log_taus(
        inv, pos, comp, n_comp, cand, rows, None, log_det, 0.0, 0.0, rtol)


@njit(cache=True)
def gathered_factored_scores(dense: np.ndarray, map_idx: np.ndarray, cand_idx: np.ndarray,
                             rtol: float) -> tuple[np.ndarray, np.ndarray, np.ndarray,
                                                   np.ndarray, int, float, np.ndarray]:
    """:func:`factored_slot_scores` with the weights gathered from a dataset's dense weight
    matrix: (map weights, A⁻¹, pos, comp, components, log det A, log τ per candidate). The
    simulator's slot then costs one kernel call; the map weights (zero diagonal: an instance
    shares no edge with itself) are returned for the policies and snapshots."""
    n, m = map_idx.size, cand_idx.size
    w = np.empty((n, n))
    for i in range(n):
        for j in range(n):
            w[i, j] = 0.0 if i == j else dense[map_idx[i], map_idx[j]]
    cand = np.empty((m, n))
    for i in range(m):
        for j in range(n):
            cand[i, j] = dense[cand_idx[i], map_idx[j]]
    inv, pos, comp, n_comp, log_det, log_tau = factored_slot_scores(w, cand, rtol)
    return w, inv, pos, comp, n_comp, log_det, log_tau
