"""Hamming distances of ORB descriptors in compiled loops: a uint64's set bits as one
POPCNT instruction, and the distances of many (row, row) pairs of two descriptor tables.

Integration looks, for every new feature of a keyframe, at the map points in view within a
few centimetres of where it lands — ~30 000 (feature, point) pairs a keyframe on the 7-Scenes
walk — and keeps those that look alike. Gathering both rows of every pair into new arrays
before XOR and popcount moved ~2 MB a keyframe; the kernel reads the rows where they are.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any, cast

import numpy as np
from numba import types
from numba.extending import intrinsic

from twinslam.kernel_cache import njit


@intrinsic
def _popcount_intrinsic(typingctx: Any, x: Any) -> Any:
    """Set bits of a uint64 via LLVM's ctpop: one POPCNT instruction on x86-64 instead of a
    dozen bit operations, in a loop over ~70 000 descriptor pairs per frame."""
    sig = types.int64(types.uint64)

    def codegen(context: Any, builder: Any, signature: Any, args: Any) -> Any:
        return builder.zext(builder.ctpop(args[0]), context.get_value_type(types.int64))

    return sig, codegen


#: what the kernels call: a uint64's set bits (typed for mypy, which cannot see numba's
#: intrinsic protocol)
popcount = cast(Callable[[int], int], _popcount_intrinsic)


@njit(cache=True)
def _pair_distances(a: np.ndarray, rows_a: np.ndarray, b: np.ndarray, rows_b: np.ndarray
                    ) -> np.ndarray:
    out = np.empty(len(rows_a), dtype=np.int64)
    for k in range(len(rows_a)):
        i, j = rows_a[k], rows_b[k]
        d = 0
        for w in range(a.shape[1]):
            d += popcount(a[i, w] ^ b[j, w])
        out[k] = d
    return out


def hamming_of_pairs(a: np.ndarray, rows_a: np.ndarray | Sequence[int], b: np.ndarray,
                     rows_b: np.ndarray | Sequence[int]) -> np.ndarray:
    """The Hamming distance of descriptor ``a[rows_a[k]]`` to ``b[rows_b[k]]`` for every k
    (``a``, ``b``: n×32 uint8 ORB descriptors): what :func:`~twinslam.slam.
    descriptor_matching.hamming_rows` gives the gathered rows, without gathering them."""
    if len(rows_a) != len(rows_b):
        raise ValueError(f"{len(rows_a)} rows of a, {len(rows_b)} of b")
    words_a = np.ascontiguousarray(a, dtype=np.uint8).view(np.uint64)
    words_b = np.ascontiguousarray(b, dtype=np.uint8).view(np.uint64)
    if words_a.shape[1:] != words_b.shape[1:] or words_a.ndim != 2:
        raise ValueError(f"descriptors of {a.shape} and {b.shape}: not rows of one length")
    ia, ib = np.asarray(rows_a, dtype=np.int64), np.asarray(rows_b, dtype=np.int64)
    # the compiled loop reads what a row names unchecked: a row outside the table is refused
    # here, as numpy's gather would refuse it
    for rows, table, name in ((ia, words_a, "a"), (ib, words_b, "b")):
        if rows.size and (rows.min() < 0 or rows.max() >= len(table)):
            raise IndexError(f"a row of {name} outside its {len(table)} descriptors")
    distances: np.ndarray = _pair_distances(words_a, ia, words_b, ib)
    return distances
