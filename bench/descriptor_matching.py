"""Descriptor matching by descriptor alone, side by side: OpenCV's ``BFMatcher.knnMatch`` (a
Python object a match, what the project used before) against faiss' exact binary index (what
:func:`twinslam.slam.descriptor_matching.match_descriptors` uses now), and the row-wise Hamming
distance by unpacked bits against numpy's ``bitwise_count``; both pairs checked to agree.

The queries are one frame's ORB features, the train sets the features of 1, 3 and 10 other
frames of the sequence (a keyframe's points, a candidate place, a local map), all extracted by
the device's own extractor.

    python -m bench.descriptor_matching [SEQUENCE] [--repeats 50]
"""

from __future__ import annotations

import argparse
import functools
import platform
import time
from collections.abc import Callable
from pathlib import Path

import cv2
import faiss
import numpy as np

from bench.paths import SEVEN_SCENES
from twinslam.sequences.opening import open_sequence
from twinslam.slam.descriptor_matching import hamming_rows, match_descriptors
from twinslam.slam.front_end.orb_extractor import OrbExtractor

DEFAULT = SEVEN_SCENES


def knn_match_objects(query: np.ndarray, train: np.ndarray, max_hamming: int, ratio: float
                      ) -> tuple[np.ndarray, np.ndarray]:
    """The matcher as it was: the same matches, read from ``BFMatcher``'s DMatch objects."""
    pairs = cv2.BFMatcher(cv2.NORM_HAMMING).knnMatch(query, train, k=2)
    q_idx, t_idx = [], []
    for pair in pairs:
        if len(pair) == 2 and pair[0].distance <= max_hamming and \
                pair[0].distance < ratio * pair[1].distance:
            q_idx.append(pair[0].queryIdx)
            t_idx.append(pair[0].trainIdx)
    q, t = np.array(q_idx, dtype=np.int64), np.array(t_idx, dtype=np.int64)
    _, first = np.unique(t, return_index=True)
    first.sort()
    return q[first], t[first]


def unpacked_rows(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The row-wise distance as it was: every bit unpacked to a byte, then counted."""
    return np.asarray(np.count_nonzero(np.unpackbits(a, axis=1) != np.unpackbits(b, axis=1),
                                       axis=1))


def median_ms(call: Callable[[], object], repeats: int) -> float:
    """Median wall time of ``call`` in milliseconds."""
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        call()
        times.append(time.perf_counter() - t0)
    return float(np.median(times)) * 1e3


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("sequence", nargs="?", default=str(DEFAULT),
                        help="RGB-D sequence (default: the bundled 7-Scenes sample; "
                             "synthetic:40 where it is missing)")
    parser.add_argument("--repeats", type=int, default=50, help="timed calls per case")
    args = parser.parse_args()
    cv2.setNumThreads(1)
    faiss.omp_set_num_threads(1)                       # a node's pools (math_threads)
    spec = args.sequence if Path(args.sequence).exists() or ":" in args.sequence \
        else "synthetic:40"
    frames = list(open_sequence(spec, 0, 40))
    extractor = OrbExtractor()
    features = [extractor.extract(f.color) for f in frames[::3]]
    query = features[0].descriptors
    print(f"machine: {platform.machine()}, python {platform.python_version()}, OpenCV "
          f"{cv2.__version__}, faiss {faiss.__version__}, one thread; {spec}: "
          f"{len(query)} query descriptors")
    print(f"{'train set':>24} {'knnMatch ms':>11} {'faiss ms':>9} {'speed-up':>8} "
          f"{'matches':>7} {'same':>5}")
    for k in (1, 3, 10):
        train = np.concatenate([f.descriptors for f in features[1:1 + k]])
        before = knn_match_objects(query, train, 50, 0.8)
        after = match_descriptors(query, train, 50, 0.8)
        same = all(np.array_equal(x, y) for x, y in zip(before, after, strict=True))
        old = median_ms(functools.partial(knn_match_objects, query, train, 50, 0.8),
                        args.repeats)
        new = median_ms(functools.partial(match_descriptors, query, train, 50, 0.8),
                        args.repeats)
        label = f"{k} frame{'s' if k > 1 else ''} ({len(train)})"
        print(f"{label:>24} {old:>11.2f} {new:>9.2f} {old / new:>7.1f}× {len(after[0]):>7} "
              f"{same!s:>5}")
    rng = np.random.default_rng(0)
    a = np.concatenate([f.descriptors for f in features])
    b = a[rng.permutation(len(a))]
    same = bool(np.array_equal(unpacked_rows(a, b), hamming_rows(a, b)))
    old = median_ms(lambda: unpacked_rows(a, b), args.repeats)
    new = median_ms(lambda: hamming_rows(a, b), args.repeats)
    print(f"row-wise Hamming distance of {len(a)} pairs: unpacked bits {old:.2f} ms, "
          f"bitwise_count {new:.2f} ms ({old / new:.0f}×), same {same}")


if __name__ == "__main__":
    main()
