"""Paired differences between policies scored on the same episodes, with a confidence
interval that counts both sources of spread a learned variant has: which training run, and
which evaluation episode.

A rule policy is one "run"; a learned variant has R training runs, each scored on the same E
episodes. The difference to a baseline rule is taken episode by episode (the same channel
realisation and start frame), and its 95 % interval comes from a two-level bootstrap: runs
drawn with replacement, then episodes drawn with replacement, the mean difference over the
drawn (run, episode) cells each time. Taking the CI over the R run means alone (as the
figures did before) ignores the episodes' spread; taking it over the R × E cells as if
independent ignores that the episodes are shared — the two-level draw does neither.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class PairedDifference:
    """mean over runs and episodes of (policy − baseline), and its 95 % bootstrap interval."""

    mean: float
    low: float
    high: float

    @property
    def apart(self) -> bool:
        """Whether the interval excludes 0: the two are told apart."""
        return self.low > 0 or self.high < 0


def paired_difference(scores: np.ndarray, baseline: np.ndarray | Sequence[float],
                      draws: int = 2000,
                      seed: int = 0) -> PairedDifference:
    """``scores``: R runs × E episodes of a policy; ``baseline``: the E episodes of the
    policy it is compared with, in the same order — or R × E, each run against its own
    baseline (a trained actor against the same run's untrained one). A fixed ``seed`` makes
    the interval reproducible."""
    scores = np.atleast_2d(np.asarray(scores, dtype=np.float64))
    base = np.asarray(baseline, dtype=np.float64)
    if base.ndim == 2:
        if base.shape != scores.shape:
            raise ValueError(f"a per-run baseline of shape {base.shape} against scores of "
                             f"{scores.shape}: a paired difference needs the same runs and "
                             "episodes")
    elif scores.shape[1] != base.size or base.size == 0:
        raise ValueError(f"{scores.shape[1]} episodes per run against {base.size} of the "
                         "baseline: a paired difference needs the same episodes")
    diff = scores - (base if base.ndim == 2 else base[None, :])
    runs, episodes = diff.shape
    if runs * episodes == 1:
        value = float(diff[0, 0])
        return PairedDifference(value, value, value)
    rng = np.random.default_rng(seed)
    r = rng.integers(0, runs, size=(draws, runs))
    e = rng.integers(0, episodes, size=(draws, episodes))
    means = np.array([diff[np.ix_(r[b], e[b])].mean() for b in range(draws)])
    low, high = np.percentile(means, [2.5, 97.5])
    return PairedDifference(float(diff.mean()), float(low), float(high))
