"""Rate states: real uplink rates (Mbit/s) cut into N states for the twin and its baselines.

The twin learns transitions between N discrete states (paper §V); a measured uplink gives real
Mbit/s. A quantiser fixes N - 1 thresholds and one representative rate per state, either over a
range the user gives (N evenly spaced rates, thresholds half way between them: the nearest
rate's state) or from a trace's own quantiles (each state holds ~1/N of the trace's slots,
represented by the median rate inside it). The rate a slot *uploads with* is never the
representative: Theorem 1 takes the real rate; the state only feeds the rate models.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class RateQuantiser:
    thresholds: np.ndarray      #: N - 1 non-decreasing Mbit/s; state i holds [t_{i-1}, t_i)
    rates: np.ndarray           #: N representative Mbit/s, one per state

    def __post_init__(self) -> None:
        t, r = np.asarray(self.thresholds, dtype=np.float64), np.asarray(self.rates, np.float64)
        if r.ndim != 1 or r.size < 1 or t.shape != (r.size - 1,):
            raise ValueError(f"{r.size} states need {r.size - 1} thresholds, got {t.shape}")
        if np.any(np.diff(t) < 0) or not np.all(np.isfinite(t)) or not np.all(np.isfinite(r)):
            raise ValueError("thresholds must be finite and non-decreasing")
        object.__setattr__(self, "thresholds", t)
        object.__setattr__(self, "rates", r)

    @property
    def n_states(self) -> int:
        return int(self.rates.size)

    def state(self, mbps: float) -> int:
        """The state of a measured rate (a rate on a threshold belongs to the upper state)."""
        if not math.isfinite(mbps):
            raise ValueError(f"rate must be finite, got {mbps}")
        return int(np.searchsorted(self.thresholds, mbps, side="right"))

    @classmethod
    def evenly(cls, n_states: int, d_min: float, d_max: float) -> RateQuantiser:
        """N rates spread evenly over [d_min, d_max]; a rate belongs to the nearest one."""
        if n_states < 1:
            raise ValueError(f"need at least one rate state, got {n_states}")
        if not (0 <= d_min <= d_max) or not math.isfinite(d_max):
            raise ValueError(f"rate range must satisfy 0 <= min <= max, got {d_min}, {d_max}")
        rates = np.linspace(d_min, d_max, n_states) if n_states > 1 else np.array([d_max])
        return cls((rates[1:] + rates[:-1]) / 2, rates)

    @classmethod
    def from_quantiles(cls, samples: np.ndarray, n_states: int) -> RateQuantiser:
        """Thresholds at the samples' i/N quantiles; each state represented by the median of
        its samples (the threshold below it when it holds none)."""
        x = np.asarray(samples, dtype=np.float64)
        if x.size == 0 or not np.all(np.isfinite(x)):
            raise ValueError("quantiles need finite samples")
        if n_states < 1:
            raise ValueError(f"need at least one rate state, got {n_states}")
        thresholds = np.quantile(x, np.arange(1, n_states) / n_states)
        states = np.searchsorted(thresholds, x, side="right")
        edges = np.concatenate([[x.min()], thresholds])
        rates = np.array([float(np.median(x[states == i])) if np.any(states == i) else edges[i]
                          for i in range(n_states)])
        return cls(thresholds, rates)
