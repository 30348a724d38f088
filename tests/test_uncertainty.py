"""The uncertainty math of paper §III-D/IV against independent computations."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from twinslam.uncertainty.map_uncertainty import (
    UncertaintyTally,
    augmented_uncertainties,
    logdet_pi,
    map_uncertainty,
    next_slot_uncertainty,
    reduced_laplacian,
    theorem1_cardinalities,
)


@st.composite
def connected_graphs(draw, max_nodes: int = 7) -> np.ndarray:
    n = draw(st.integers(2, max_nodes))
    w = np.zeros((n, n))
    for v in range(1, n):  # a random spanning tree keeps it connected
        u = draw(st.integers(0, v - 1))
        w[u, v] = w[v, u] = draw(st.integers(1, 30))
    for u, v in itertools.combinations(range(n), 2):
        if w[u, v] == 0 and draw(st.booleans()):
            w[u, v] = w[v, u] = draw(st.integers(1, 30))
    return w


def _root(parent: list[int], x: int) -> int:
    while parent[x] != x:
        parent[x] = parent[parent[x]]
        x = parent[x]
    return x


def spanning_tree_count(w: np.ndarray) -> float:
    """Σ over spanning trees of the product of edge weights, by brute-force enumeration."""
    n = w.shape[0]
    edges = [(u, v) for u, v in itertools.combinations(range(n), 2) if w[u, v] > 0]
    total = 0.0
    for subset in itertools.combinations(edges, n - 1):
        parent = list(range(n))
        acyclic = True
        for u, v in subset:
            ru, rv = _root(parent, u), _root(parent, v)
            if ru == rv:
                acyclic = False
                break
            parent[ru] = rv
        if acyclic:
            total += math.prod(w[u, v] for u, v in subset)
    return total


@settings(max_examples=60, deadline=None)
@given(w=connected_graphs())
def test_det_reduced_laplacian_is_the_weighted_spanning_tree_count(w: np.ndarray) -> None:
    det = np.linalg.det(reduced_laplacian(w))  # a plain determinant is fine at this size
    count = spanning_tree_count(w)
    assert det == pytest.approx(count, rel=1e-9)
    assert map_uncertainty(w) == pytest.approx(-6 * math.log(count), rel=1e-9, abs=1e-9)


@settings(max_examples=60, deadline=None)
@given(w=connected_graphs(), data=st.data())
def test_uncertainty_is_invariant_under_relabelling(w: np.ndarray, data) -> None:
    perm = np.array(data.draw(st.permutations(range(w.shape[0]))))
    assert map_uncertainty(w[np.ix_(perm, perm)]) == pytest.approx(map_uncertainty(w), abs=1e-8)


@settings(max_examples=60, deadline=None)
@given(w=connected_graphs(max_nodes=6), data=st.data())
def test_lemma1_adding_a_connected_frame_lowers_u(w: np.ndarray, data) -> None:
    n = w.shape[0]
    b = np.array(data.draw(st.lists(st.integers(0, 20), min_size=n, max_size=n)), dtype=float)
    if b.sum() == 0:
        b[data.draw(st.integers(0, n - 1))] = 1
    grown = np.zeros((n + 1, n + 1))
    grown[:n, :n], grown[n, :n], grown[:n, n] = w, b, b
    pi_scale = data.draw(st.sampled_from([1.0, 1.5]))
    ld_pi = logdet_pi(pi_scale * np.eye(6))
    before, after = map_uncertainty(w, ld_pi), map_uncertainty(grown, ld_pi)
    if b.sum() > 1 or ld_pi > 0:
        assert after < before
    else:
        # One shared point and det Π = 1: κ is unchanged, so u is too (Lemma 1 is not strict).
        assert after == pytest.approx(before)
    # The batched candidate formula agrees with the fresh computation.
    assert augmented_uncertainties(w, b[None, :], ld_pi)[0] == pytest.approx(after, abs=1e-8)


def test_disconnected_map_is_infinite_and_so_are_its_augmentations() -> None:
    w = np.zeros((4, 4))
    w[0, 1] = w[1, 0] = 5
    w[2, 3] = w[3, 2] = 7
    assert map_uncertainty(w) == math.inf
    assert augmented_uncertainties(w, np.array([[1.0, 0, 0, 0]]))[0] == math.inf
    # ...unless the new frame bridges the two components.
    assert math.isfinite(augmented_uncertainties(w, np.array([[1.0, 0, 2, 0]]))[0])


def test_a_lost_frame_scores_as_a_frame_with_no_map_and_never_leaks_inf() -> None:
    w = np.array([[0, 10], [10, 0]], dtype=float)
    cand = np.array([[3, 4], [0, 0], [5, 0]], dtype=float)
    slot = next_slot_uncertainty(w, cand)
    assert slot.lost_share == pytest.approx(1 / 3)
    u = augmented_uncertainties(w, cand)
    assert slot.tracked_uncertainty == pytest.approx(np.mean(u[[0, 2]]))
    assert slot.objective == pytest.approx((u[0] + u[2] + 0.0) / 3)      # lost: u = 0
    assert slot.objective == pytest.approx((1 - slot.lost_share) * slot.tracked_uncertainty)
    assert slot.reward == -slot.objective
    # losing the frame is worse than tracking it, however weakly: u(G ∪ {f}) < 0
    weakly = next_slot_uncertainty(w, np.array([[3, 4], [1, 0], [5, 0]], dtype=float))
    assert weakly.objective < slot.objective


def test_pooled_scores_keep_mean_equal_lost_times_tracked() -> None:
    w = np.array([[0, 10], [10, 0]], dtype=float)
    slots = [next_slot_uncertainty(w, np.array(c, dtype=float)) for c in
             ([[3, 4], [0, 0], [5, 0]], [[1, 1]], [[0, 0], [0, 0]])]
    pooled = UncertaintyTally.of(slots)
    assert pooled.n_frames == 6 and pooled.n_tracked == 3
    assert pooled.lost_share == pytest.approx(0.5)
    assert pooled.mean == pytest.approx((1 - pooled.lost_share) * pooled.tracked_uncertainty)
    assert math.isnan(slots[2].tracked_uncertainty) and slots[2].objective == 0.0


def test_a_disconnected_map_that_every_next_frame_bridges_has_a_finite_objective() -> None:
    # found by the learner: the map's u is +inf, no frame is lost, and 0 lost x inf gave NaN
    w = np.zeros((4, 4))
    w[0, 1] = w[1, 0] = 5
    w[2, 3] = w[3, 2] = 7
    cand = np.array([[1.0, 0, 2, 0], [0, 3.0, 0, 1.0]])
    slot = next_slot_uncertainty(w, cand)
    assert slot.lost_share == 0.0 and slot.map_uncertainty == math.inf
    assert slot.objective == pytest.approx(np.mean(augmented_uncertainties(w, cand)))
    assert math.isfinite(slot.reward)


def test_theorem1_cardinalities_keep_the_map_at_vmax() -> None:
    assert theorem1_cardinalities(80, 5, 0.5, 45, 45, 60) == (8, 8)
    assert theorem1_cardinalities(40, 5, 0.5, 45, 45, 60) == (4, 4)
    assert theorem1_cardinalities(80, 5, 0.5, 45, 10, 60) == (8, 0)   # map still filling up
    assert theorem1_cardinalities(80, 5, 0.5, 45, 40, 60) == (8, 3)
    assert theorem1_cardinalities(80, 5, 0.5, 45, 45, 3) == (3, 3)    # slot holds fewer frames
    with pytest.raises(ValueError, match="rate"):
        theorem1_cardinalities(float("nan"), 5, 0.5, 45, 45, 60)
    with pytest.raises(ValueError, match="rate"):
        theorem1_cardinalities(-1, 5, 0.5, 45, 45, 60)
