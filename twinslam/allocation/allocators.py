"""One edge, many devices: splitting the keyframe budget V_total between the devices' maps
(docs/architecture.md §10, the paper's future work).

Each device's map is managed by its own policy exactly as with one device; what changes is
its V_max, which is the share an allocator gives it, slot by slot. Three allocators:

* ``equal`` — V_total / N each (the remainder to the devices holding most now, so nobody
  evicts for a rounding).
* ``motion`` — in proportion to each device's *novelty*: the share of the points its last
  slot's frames saw that its map does not hold. A device walking into new ground needs
  keyframes to keep up with it; one standing still is served by the map it has.
* ``value`` — each device's predicted tracked share as a function of its budget
  (:mod:`twinslam.allocation.budget_value`: its recent frames against its map and the
  uploads its rate twin expects), keyframes handed out one at a time to the largest gain in
  Σ U(value), with U α-fair (``fairness`` 0: the sum itself; 1: Σ log, proportional
  fairness). It is called ``twin``: the twin is what says how many uploads to expect.

Every allocator gives each device at least ``minimum`` keyframes; V_total below N × minimum
is refused with the reason. Jain's index says how evenly a per-device figure came out.
"""

from __future__ import annotations

import heapq
import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

#: allocator names (``twin`` is ``value`` fed by the devices' rate twins)
ALLOCATORS = ("equal", "motion", "twin")


class BudgetError(ValueError):
    """A budget that cannot be split as asked (V_total below N × the minimum)."""


@dataclass(frozen=True)
class DeviceDemand:
    """What the edge knows of one device when it splits the budget: nothing of the future.

    ``value[b]`` (for ``twin``) is the device's predicted tracked share with a budget of b
    keyframes, b = 0 … len − 1 (beyond, it stays at the last value)."""

    device: str
    map_size: int = 0
    novelty: float = 0.0
    value: np.ndarray | None = None


def check_budget(total: int, n_devices: int, minimum: int) -> None:
    """BudgetError naming why ``total`` keyframes cannot serve ``n_devices``."""
    if minimum < 1:
        raise BudgetError(f"each device needs a budget of at least 1 keyframe, got {minimum}")
    if n_devices and total < n_devices * minimum:
        raise BudgetError(f"V_total {total} is below {n_devices} devices x {minimum} keyframes "
                          "each: serve fewer devices, lower the minimum or raise V_total")


def check_fleet(devices: int, allocator: str, total: int, minimum: int) -> None:
    """ValueError naming what stops ``devices`` from sharing ``total`` keyframes by
    ``allocator`` (``total`` 0: no shared budget, only the rest is checked)."""
    if devices < 1:
        raise ValueError(f"a fleet needs at least one device, got {devices}")
    if allocator not in ALLOCATORS:
        raise ValueError(f"unknown allocator {allocator!r}: one of {', '.join(ALLOCATORS)}")
    if total:
        check_budget(total, devices, minimum)


def split_equal(total: int, held: Sequence[int], minimum: int) -> list[int]:
    """V_total / N each; the remainder to the devices holding most now (``held``)."""
    n = len(held)
    check_budget(total, n, minimum)
    if n == 0:
        return []
    base, extra = divmod(total, n)
    order = sorted(range(n), key=lambda i: (-held[i], i))
    shares = [base] * n
    for i in order[:extra]:
        shares[i] += 1
    return shares


def split_proportional(total: int, weights: Sequence[float], minimum: int) -> list[int]:
    """``minimum`` each and the rest in proportion to ``weights`` (largest remainders; equal
    shares when every weight is 0)."""
    n = len(weights)
    check_budget(total, n, minimum)
    if n == 0:
        return []
    w = np.asarray(weights, dtype=np.float64)
    if not np.all(np.isfinite(w)) or np.any(w < 0):
        raise ValueError(f"weights must be finite and >= 0, got {list(weights)}")
    if w.sum() <= 0:
        w = np.ones(n)
    spare = total - n * minimum
    exact = spare * w / w.sum()
    shares = np.floor(exact).astype(np.int64)
    left = spare - int(shares.sum())
    order = np.lexsort((np.arange(n), -(exact - shares)))     # largest remainder first
    shares[order[:left]] += 1
    return [int(s) + minimum for s in shares]


def utility(share: np.ndarray, fairness: float) -> np.ndarray:
    """α-fair utility of tracked shares: α = 0 the share itself, α = 1 its log, else
    x^(1-α)/(1-α); a share is floored at 1e-3 so a device tracking nothing still counts."""
    x = np.maximum(np.asarray(share, dtype=np.float64), 1e-3)
    if fairness == 0:
        return x
    if fairness == 1:
        return np.log(x)
    return np.power(x, 1 - fairness) / (1 - fairness)


def split_by_value(total: int, values: Sequence[np.ndarray], minimum: int,
                   fairness: float = 0.0) -> list[int]:
    """Maximise Σ_i U(values_i[b_i]) over Σ b_i = ``total``, b_i ≥ ``minimum``: greedy on
    each curve's concave envelope, which is exact for concave utilities of concave curves
    and a sound heuristic otherwise (a curve that rises late is still reached through its
    envelope's average gain). Keyframes no curve gains from go round-robin to the smallest
    shares: a spare keyframe still helps a device that turns back."""
    n = len(values)
    check_budget(total, n, minimum)
    if fairness < 0 or not math.isfinite(fairness):
        raise ValueError(f"fairness must be >= 0, got {fairness}")
    if n == 0:
        return []
    shares = [minimum] * n
    # each curve's own length: past its end it is flat, and a flat stretch gains nothing
    gains = [_envelope_gains(utility(_clip(v, total), fairness)) for v in values]

    def gain(i: int) -> float:
        return float(gains[i][shares[i]]) if shares[i] < len(gains[i]) else 0.0

    # the largest gain first (ties: the lower index), by a heap: O(V_total log N)
    heap = [(-gain(i), i) for i in range(n)]
    heapq.heapify(heap)
    left = total - n * minimum
    while left and heap and -heap[0][0] > 1e-12:
        _, i = heapq.heappop(heap)
        shares[i] += 1
        left -= 1
        heapq.heappush(heap, (-gain(i), i))
    # keyframes nobody gains from: evenly, the smallest shares first
    smallest = [(shares[j], j) for j in range(n)]
    heapq.heapify(smallest)
    for _ in range(left):
        _, i = heapq.heappop(smallest)
        shares[i] += 1
        heapq.heappush(smallest, (shares[i], i))
    return shares


def _clip(value: np.ndarray, total: int) -> np.ndarray:
    """``value`` over budgets 0 … at most ``total`` (checked: finite, non-empty, 1-d)."""
    v = np.asarray(value, dtype=np.float64)
    if v.ndim != 1 or v.size == 0 or not np.all(np.isfinite(v)):
        raise ValueError("a value curve is a non-empty 1-d array of finite shares")
    return v[:total + 1]


def _envelope_gains(u: np.ndarray) -> np.ndarray:
    """Gains g[b] = U(b+1) − U(b) of the least concave majorant of ``u`` (upper hull)."""
    hull: list[int] = [0]
    for b in range(1, u.size):
        while len(hull) >= 2:
            a, c = hull[-2], hull[-1]
            # drop c when it lies on or under the chord from a to b
            if (u[c] - u[a]) * (b - a) <= (u[b] - u[a]) * (c - a):
                hull.pop()
            else:
                break
        hull.append(b)
    gains = np.zeros(max(u.size - 1, 0))
    for a, b in itertools.pairwise(hull):
        gains[a:b] = (u[b] - u[a]) / (b - a)
    return gains


def allocate(allocator: str, total: int, demands: Sequence[DeviceDemand], minimum: int,
             fairness: float = 0.0) -> list[int]:
    """Each device's keyframe budget by ``allocator`` (one of :data:`ALLOCATORS`)."""
    if allocator == "equal":
        return split_equal(total, [d.map_size for d in demands], minimum)
    if allocator == "motion":
        return split_proportional(total, [max(d.novelty, 0.0) for d in demands], minimum)
    if allocator == "twin":
        missing = [d.device for d in demands if d.value is None]
        if missing:
            raise ValueError(f"the twin allocator needs a value curve for {', '.join(missing)}")
        return split_by_value(total, [d.value for d in demands if d.value is not None],
                              minimum, fairness)
    raise ValueError(f"unknown allocator {allocator!r}: one of {', '.join(ALLOCATORS)}")


def split_capacity(capacity: float, links: Sequence[float], weights: Sequence[float]
                   ) -> list[float]:
    """A shared cell's ``capacity`` split in proportion to ``weights``, no device above its
    own link's rate (``links``): what a capped device cannot use goes to the others in the
    same proportions (water-filling). Equal weights when all are 0; every device gets its link
    when the capacity covers them all."""
    n = len(links)
    if len(weights) != n:
        raise ValueError(f"{len(weights)} weights for {n} links")
    link = np.asarray(links, dtype=np.float64)
    w = np.asarray(weights, dtype=np.float64)
    if capacity < 0 or np.any(link < 0) or np.any(w < 0) or not np.all(np.isfinite(w)):
        raise ValueError("capacity, link rates and weights must be >= 0")
    if n == 0 or link.sum() <= capacity:
        return [float(x) for x in link]
    # scaled by the largest first: a denormal weight alone would otherwise round its share up
    w = w / w.max() if w.max() > 0 else np.ones(n)
    out = np.zeros(n)
    free = np.ones(n, dtype=bool)
    left = float(capacity)
    while left > 1e-12 and free.any():
        weight = np.where(free, w, 0.0)
        if weight.sum() <= 0:                      # the rest have no weight: equal among them
            weight = free.astype(np.float64)
        offer = left * (weight / weight.sum())
        capped = free & (out + offer >= link)
        if not capped.any():
            out += offer
            break
        left -= float((link[capped] - out[capped]).sum())
        out[capped] = link[capped]
        free &= ~capped
    return [float(x) for x in out]


def jain_index(values: Sequence[float]) -> float:
    """Jain's fairness index (Σx)² / (N Σx²): 1 when all are equal, 1/N when one has all;
    NaN without values, 1 when all are 0."""
    x = np.asarray([v for v in values if math.isfinite(v)], dtype=np.float64)
    if x.size == 0:
        return math.nan
    square = float(np.sum(x * x))
    return 1.0 if square == 0 else float(np.sum(x) ** 2 / (x.size * square))
