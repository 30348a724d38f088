"""ADAPT's greedy by its definition: every determinant recomputed from scratch.

The compiled greedy (:mod:`twinslam.uncertainty.greedy_kernels`) takes shortcuts — low-rank
updates, pruned scoring — that must pick exactly what this does. The tests check that they do,
and ``bench.sim`` measures what the shortcuts buy against it. Slow by design (O(n⁴) a step);
never on a policy's path.
"""

from __future__ import annotations

import numpy as np

from twinslam.uncertainty.laplacian_factorization import pick_best
from twinslam.uncertainty.map_uncertainty import logdet_spd, reduced_laplacian


def naive_greedy(weights: np.ndarray, start: list[int], pool: list[int], n_add: int,
                 n_remove: int) -> tuple[list[int], list[int]]:
    """ADAPT's greedy recomputing every determinant from scratch: additions to ``start`` from
    ``pool``, then removals from the union (oldest frame wins ties)."""
    current = list(start)
    added: list[int] = []
    remaining = list(pool)
    for _ in range(n_add):
        if not current:
            scores = np.array([weights[v, remaining].sum() for v in remaining], dtype=float)
        else:
            scores = np.array([logdet_spd(reduced_laplacian(
                weights[np.ix_([*current, v], [*current, v])])) for v in remaining])
        v = remaining[pick_best(scores)]
        added.append(v)
        current.append(v)
        remaining.remove(v)
    removed: list[int] = []
    order = sorted(current)
    for _ in range(n_remove):
        if len(order) <= 2:
            v = order[0]
        else:
            scores = np.array([logdet_spd(reduced_laplacian(
                weights[np.ix_([x for x in order if x != v], [x for x in order if x != v])]))
                for v in order])
            v = order[pick_best(scores)]
        removed.append(v)
        order.remove(v)
    return added, removed
