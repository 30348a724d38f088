"""Matching ORB descriptors by descriptor alone: the nearest train descriptor of each query,
kept when it is within the Hamming cap and clearly nearer than the runner-up (Lowe's ratio),
one query per train descriptor."""

from __future__ import annotations

import numpy as np

from twinslam.slam.descriptor_matching import hamming_rows, match_descriptors


def _bits(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Every query's Hamming distance to every train descriptor, bit by bit."""
    return (np.unpackbits(a[:, None, :], axis=2) != np.unpackbits(b[None, :, :], axis=2)
            ).sum(axis=2)


def _expected(query: np.ndarray, train: np.ndarray, cap: int, ratio: float
              ) -> tuple[list[int], list[int]]:
    d = _bits(query, train)
    q_out: list[int] = []
    t_out: list[int] = []
    for q in range(len(query)):
        order = np.argsort(d[q], kind="stable")
        best, second = d[q, order[0]], d[q, order[1]]
        if best <= cap and best < ratio * second and order[0] not in t_out:
            q_out.append(q)
            t_out.append(int(order[0]))
    return q_out, t_out


def test_matches_are_the_ratio_tests_nearest_neighbours_one_per_train_descriptor() -> None:
    rng = np.random.default_rng(3)
    for _ in range(40):
        train = rng.integers(0, 256, (int(rng.integers(2, 300)), 32), dtype=np.uint8)
        n = int(rng.integers(1, 200))
        query = rng.integers(0, 256, (n, 32), dtype=np.uint8)
        # half the queries are noisy copies of train descriptors (several of the same one)
        src = rng.integers(0, len(train), n // 2)
        flips = (rng.random((n // 2, 32, 8)) < rng.uniform(0.0, 0.15)).astype(np.uint8)
        query[:n // 2] = train[src] ^ np.packbits(flips, axis=2)[..., 0]
        cap, ratio = int(rng.integers(30, 90)), float(rng.uniform(0.6, 0.95))
        q, t = match_descriptors(query, train, cap, ratio)
        assert (q.tolist(), t.tolist()) == _expected(query, train, cap, ratio)


def test_a_best_match_tied_with_the_runner_up_is_no_match() -> None:
    train = np.zeros((3, 32), dtype=np.uint8)
    train[1, 0] = 0b1                                  # 1 bit from the query
    train[2, 0] = 0b10                                 # also 1 bit: a tie for the nearest
    query = np.zeros((1, 32), dtype=np.uint8)
    query[0, 0] = 0b11
    q, t = match_descriptors(query, train, 50, 0.99)
    assert q.size == 0 and t.size == 0


def test_too_few_descriptors_to_rank_match_nothing() -> None:
    one = np.zeros((1, 32), dtype=np.uint8)
    assert match_descriptors(one, one, 50, 0.8)[0].size == 0
    assert match_descriptors(np.zeros((0, 32), np.uint8), np.zeros((5, 32), np.uint8),
                             50, 0.8)[0].size == 0


def test_row_distances_count_the_bits_that_differ() -> None:
    rng = np.random.default_rng(4)
    a = rng.integers(0, 256, (500, 32), dtype=np.uint8)
    b = rng.integers(0, 256, (500, 32), dtype=np.uint8)
    assert hamming_rows(a, b).tolist() == [int(_bits(a[i:i + 1], b[i:i + 1])[0, 0])
                                           for i in range(500)]
    assert hamming_rows(a, a).tolist() == [0] * 500
