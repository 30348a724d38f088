"""The Laplacian factorization's shortcuts (one factorisation, low-rank queries, incremental
updates, bounds) against spanning-tree counts recomputed from scratch for every query."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tests.laplacian_reference import best_removal, removal_log_tau, with_frame, without_frame
from tests.test_uncertainty import spanning_tree_count
from twinslam.uncertainty import laplacian_kernels as kernels
from twinslam.uncertainty.laplacian_factorization import LaplacianFactorization, pick_best
from twinslam.uncertainty.map_uncertainty import logdet_spd, reduced_laplacian


@st.composite
def any_graphs(draw, min_nodes: int = 1, max_nodes: int = 9) -> np.ndarray:
    """Symmetric weights, connected or not (each edge present with a drawn probability)."""
    n = draw(st.integers(min_nodes, max_nodes))
    density = draw(st.sampled_from([0.15, 0.4, 0.8]))
    w = np.zeros((n, n))
    for u, v in itertools.combinations(range(n), 2):
        if draw(st.floats(0, 1)) < density:
            w[u, v] = w[v, u] = draw(st.integers(1, 300))
    return w


def log_tau(w: np.ndarray) -> float:
    """log of the weighted spanning-tree count from a fresh Cholesky (-inf if disconnected)."""
    return logdet_spd(reduced_laplacian(w)) if w.shape[0] else -math.inf


def close(a: float, b: float) -> bool:
    return a == b or abs(a - b) <= 1e-9 * max(1.0, abs(b))


@settings(max_examples=150, deadline=None)
@given(any_graphs(min_nodes=2))
def test_augmented_scores_equal_a_fresh_factorisation(w: np.ndarray) -> None:
    """Every frame scored against the rest, including frames that bridge a disconnected map
    (scored through its per-component grounds) and frames that share nothing (-inf)."""
    n = w.shape[0]
    for f in range(n):
        rest = [i for i in range(n) if i != f]
        factor = LaplacianFactorization(w[np.ix_(rest, rest)])
        got = float(factor.augmented_log_tau(w[f, rest][None, :])[0])
        assert close(got, log_tau(w[np.ix_([*rest, f], [*rest, f])]))


def test_a_bridging_frame_is_scored_exactly() -> None:
    # Two triangles that share no point; frame 6 sees both. Its τ is known in closed form:
    # each triangle with unit weights has 3 spanning trees, joined through the bridge frame.
    w = np.zeros((7, 7))
    for a, b in [(0, 1), (1, 2), (0, 2), (3, 4), (4, 5), (3, 5)]:
        w[a, b] = w[b, a] = 1.0
    w[6, 1] = w[1, 6] = 2.0
    w[6, 4] = w[4, 6] = 5.0
    factor = LaplacianFactorization(w[:6, :6])
    assert factor.n_comp == 2 and factor.log_tau == -math.inf
    expected = math.log(3 * 3 * 2 * 5)
    assert close(float(factor.augmented_log_tau(w[6, :6][None, :])[0]), expected)
    assert close(expected, math.log(spanning_tree_count(w)))
    # a frame touching only one triangle leaves the map disconnected
    assert factor.augmented_log_tau(np.array([[0, 3.0, 0, 0, 0, 0]]))[0] == -math.inf


@settings(max_examples=150, deadline=None)
@given(any_graphs(min_nodes=3))
def test_removal_scores_equal_a_fresh_factorisation(w: np.ndarray) -> None:
    n = w.shape[0]
    factor = LaplacianFactorization(w)
    scores = removal_log_tau(factor)
    for v in range(n):
        rest = [i for i in range(n) if i != v]
        assert close(float(scores[v]), log_tau(w[np.ix_(rest, rest)]))
    best, score = best_removal(factor)            # the pruned search picks the same frame
    assert best == pick_best(scores) and close(score, float(scores[best]))


def _same_inverse(updated: np.ndarray, fresh: np.ndarray) -> None:
    """An updated inverse equals a fresh one to rounding: relatively where an entry is not
    zero, and within rounding of the matrix's own scale where it is — an update's zero comes
    out as the difference of entries of that scale (1.1e-12 where the entries reach 3.7 and
    an absolute bound of 1e-12 had been asked for)."""
    scale = max(1.0, float(np.abs(fresh).max(initial=0.0)))
    np.testing.assert_allclose(updated, fresh, rtol=1e-8,
                               atol=1e-12 * scale * max(1, fresh.shape[0]))


@settings(max_examples=100, deadline=None)
@given(any_graphs(min_nodes=2), st.data())
def test_incremental_updates_equal_refactorising(w: np.ndarray, data) -> None:
    n = w.shape[0]
    base = LaplacianFactorization(w[:-1, :-1])
    score = float(base.augmented_log_tau(w[-1, :-1][None, :])[0])
    grown, fresh = with_frame(base, w[-1, :-1], score), LaplacianFactorization(w)
    assert grown.n_comp == fresh.n_comp and close(grown.log_tau, fresh.log_tau)
    if fresh.connected:
        _same_inverse(grown.inverse, fresh.inverse)
    v = data.draw(st.integers(0, n - 1))               # 0 is the ground: re-grounds at frame 1
    removal = float(removal_log_tau(fresh)[v]) if n > 2 else 0.0
    shrunk = without_frame(fresh, v, removal)
    rest = [i for i in range(n) if i != v]
    again = LaplacianFactorization(w[np.ix_(rest, rest)])
    assert close(shrunk.log_tau, again.log_tau)
    if again.connected and n > 1:
        _same_inverse(shrunk.inverse, again.inverse)


@settings(max_examples=150, deadline=None)
@given(any_graphs(min_nodes=4, max_nodes=10), st.data())
def test_addition_bounds_hold_after_the_set_grows(w: np.ndarray, data) -> None:
    """The lazy greedy's premise: a candidate's ratio in S ∪ {v} is at most its carried bound."""
    n = w.shape[0]
    s_size = data.draw(st.integers(1, n - 2))
    s, v, cands = list(range(s_size)), s_size, list(range(s_size + 1, n))
    before = LaplacianFactorization(w[np.ix_(s, s)])
    after = with_frame(before, w[v, s])
    if not (before.connected and after.connected):
        return                                          # bounds are only carried then
    cand_to_s = np.ascontiguousarray(w[np.ix_(cands, s)])
    upper = before.augmented_log_tau(cand_to_s) - before.log_det_a
    upper[~np.isfinite(upper)] = math.inf              # unknown, as the greedy stores it
    kernels.raise_addition_bounds(after.inverse, after.pos, cand_to_s,
                                  np.ascontiguousarray(w[cands, v]),
                                  np.arange(len(cands)), upper)
    exact = after.augmented_log_tau(w[np.ix_(cands, [*s, v])]) - after.log_det_a
    assert np.all(exact <= upper + 1e-9 * np.maximum(1.0, np.abs(upper)))


@settings(max_examples=150, deadline=None)
@given(any_graphs(min_nodes=1, max_nodes=9), st.integers(1, 5), st.data())
def test_hadamard_addition_bounds_hold(w: np.ndarray, k: int, data) -> None:
    """The first greedy round's pruning premise: on any set, connected or not, no candidate's
    exact ratio exceeds its Hadamard bound, and a bound is -inf exactly when the exact score
    is (the candidate leaves a component untouched)."""
    n = w.shape[0]
    cand = np.array([[data.draw(st.sampled_from([0, 0, 1, 7, 40])) for _ in range(n)]
                     for _ in range(k)], dtype=float)
    factor = LaplacianFactorization(w)
    exact = factor.augmented_log_tau(cand) - factor.log_det_a
    upper = np.full(k, math.inf)
    kernels.tighten_addition_bounds(factor.inverse, factor.pos, factor.comp, factor.n_comp,
                                    cand, np.arange(k), upper)
    assert np.array_equal(np.isinf(upper) & (upper < 0), np.isinf(exact) & (exact < 0))
    finite = np.isfinite(exact)
    assert np.all(exact[finite] <= upper[finite] + 1e-9 * np.maximum(1.0, np.abs(upper[finite])))


@settings(max_examples=80, deadline=None)
@given(any_graphs(min_nodes=2, max_nodes=8), st.integers(1, 4), st.data())
def test_slot_uncertainty_equals_per_frame_factorisations(w: np.ndarray, k: int, data) -> None:
    """υ_k's one-call path (kernels.slot_scores) against a fresh Cholesky per next-slot frame."""
    from twinslam.uncertainty.map_uncertainty import map_uncertainty, next_slot_uncertainty

    n = w.shape[0]
    cand = np.array([[data.draw(st.sampled_from([0, 0, 1, 7, 40])) for _ in range(n)]
                     for _ in range(k)], dtype=float)
    slot = next_slot_uncertainty(w, cand)
    u = []
    for row in cand:
        full = np.zeros((n + 1, n + 1))
        full[:n, :n], full[n, :n], full[:n, n] = w, row, row
        u.append(-6.0 * log_tau(full))
    u = np.array(u)
    tracked = np.isfinite(u)
    assert slot.lost_share == pytest.approx(1 - tracked.mean())
    assert close(slot.map_uncertainty, map_uncertainty(w))
    if tracked.any():
        assert close(slot.tracked_uncertainty, float(u[tracked].mean()))
    assert close(slot.objective, float(u[tracked].sum()) / len(u))     # a lost frame: u = 0
