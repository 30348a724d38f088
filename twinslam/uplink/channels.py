"""Uplink channel models: the rate d_k of every slot (paper §III-C).

Inside an interval of K slots the rate follows an N-state Markov chain with one transition
matrix; across intervals the matrix may change (the hidden x_t). ``MarkovChannel`` generates
such rates, stationary (one matrix for all intervals) or non-stationary (a new matrix drawn per
interval). ``TraceChannel`` replays a measured throughput trace instead.

Trace file format (CSV, one header line): ``time_s,throughput_mbps``, time strictly
increasing, throughput finite and >= 0. Each slot takes the mean throughput over its time
window; the trace is scaled linearly onto the configured rate range and quantised to the
nearest of N states.
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from twinslam.common import table1


class ChannelError(ValueError):
    """A bad channel specification or trace file; the message names the file and line."""


def state_rates(n_states: int, d_min: float = 40.0, d_max: float = 80.0) -> np.ndarray:
    """The N rates (Mbit/s) spread evenly over [d_min, d_max]."""
    if n_states < 1:
        raise ChannelError(f"need at least one channel state, got {n_states}")
    if not (0 < d_min <= d_max) or not math.isfinite(d_max):
        raise ChannelError(f"rate range must satisfy 0 < d_min <= d_max, got {d_min}, {d_max}")
    return np.linspace(d_min, d_max, n_states) if n_states > 1 else np.array([d_max])


def random_transition_matrix(rng: np.random.Generator, n_states: int,
                             concentration: float = 1.0) -> np.ndarray:
    """A row-stochastic matrix with Dirichlet(concentration) rows."""
    return rng.dirichlet(np.full(n_states, concentration), size=n_states)


def balanced_transition_matrix(rng: np.random.Generator, n_states: int,
                               concentration: float = 1.0, sweeps: int = 200) -> np.ndarray:
    """A random doubly stochastic matrix (Dirichlet rows, then Sinkhorn sweeps): its
    stationary distribution is uniform, so every such chain has the same mean rate — the mean
    of the N rates — whatever N (paper Fig. 8 compares N = 2 and N = 4 at one mean rate)."""
    m = random_transition_matrix(rng, n_states, concentration) + 1e-9
    for _ in range(sweeps):
        m /= m.sum(axis=0, keepdims=True)
        m /= m.sum(axis=1, keepdims=True)
    return m


def two_state_matrix(high_ratio: float, switch_rate: float = 0.3) -> np.ndarray:
    """2-state chain whose stationary share of high-rate slots is ``high_ratio`` (paper Fig. 7).

    P = [[1-a, a], [b, 1-b]] with a + b = switch_rate and a / (a + b) = high_ratio.
    """
    if not 0.0 < high_ratio < 1.0:
        raise ChannelError(f"high-rate ratio must lie in (0, 1), got {high_ratio}")
    if not 0.0 < switch_rate <= 1.0:
        raise ChannelError(f"switch rate must lie in (0, 1], got {switch_rate}")
    a, b = high_ratio * switch_rate, (1.0 - high_ratio) * switch_rate
    return np.array([[1.0 - a, a], [b, 1.0 - b]])


def check_transition_matrix(matrix: np.ndarray) -> np.ndarray:
    m = np.asarray(matrix, dtype=np.float64)
    if m.ndim != 2 or m.shape[0] != m.shape[1]:
        raise ChannelError(f"transition matrix must be square, got shape {m.shape}")
    if not np.all(np.isfinite(m)) or np.any(m < 0) or not np.allclose(m.sum(axis=1), 1.0):
        raise ChannelError("transition matrix rows must be probability distributions")
    return m


@dataclass
class MarkovChannel:
    """N-state Markov rates; the matrix is redrawn every ``interval_slots`` if non-stationary."""

    rates: np.ndarray
    interval_slots: int = 100
    stationary: bool = True
    matrix: np.ndarray | None = None        #: fixed matrix (stationary) or the first one
    concentration: float = 1.0
    balanced: bool = False                  #: draw doubly stochastic matrices (uniform rates)
    seed: int = 0
    _rng: np.random.Generator = field(init=False, repr=False)
    _state: int = field(init=False, default=0)
    _slot: int = field(init=False, default=0)
    _current: np.ndarray = field(init=False, repr=False)
    matrices: list[np.ndarray] = field(init=False, default_factory=list)

    def __post_init__(self) -> None:
        self.rates = np.asarray(self.rates, dtype=np.float64)
        if self.interval_slots < 1:
            raise ChannelError("interval_slots must be >= 1")
        if self.matrix is not None:
            self.matrix = check_transition_matrix(self.matrix)
            if self.matrix.shape[0] != self.rates.size:
                raise ChannelError(f"{self.matrix.shape[0]}-state matrix for "
                                   f"{self.rates.size} rates")
        self.reset(self.seed)

    @property
    def n_states(self) -> int:
        return int(self.rates.size)

    def reset(self, seed: int | None = None) -> None:
        self._rng = np.random.default_rng(self.seed if seed is None else seed)
        self._slot = 0
        self.matrices = []
        self._current = self._draw_matrix()
        self._state = int(self._rng.integers(self.n_states))

    def _draw_matrix(self) -> np.ndarray:
        if self.matrix is not None and (self.stationary or not self.matrices):
            m = self.matrix
        elif self.balanced:
            m = balanced_transition_matrix(self._rng, self.n_states, self.concentration)
        else:
            m = random_transition_matrix(self._rng, self.n_states, self.concentration)
        self.matrices.append(m)
        return m

    @property
    def current_matrix(self) -> np.ndarray:
        return self._current

    def step(self) -> tuple[int, float]:
        """(state index, rate in Mbit/s) of the next slot."""
        if self._slot > 0:
            if not self.stationary and self._slot % self.interval_slots == 0:
                self._current = self._draw_matrix()
            self._state = int(self._rng.choice(self.n_states, p=self._current[self._state]))
        self._slot += 1
        return self._state, float(self.rates[self._state])


def read_trace(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Parse a ``time_s,throughput_mbps`` CSV; refuse bad values naming file and line."""
    path = Path(path)
    if not path.is_file():
        raise ChannelError(f"trace file {path} does not exist")
    times: list[float] = []
    values: list[float] = []
    with path.open(newline="", encoding="utf-8") as fh:
        reader = csv.reader(fh)
        header = next(reader, None)
        if header is None:
            raise ChannelError(f"{path}: empty trace file")
        if [h.strip() for h in header] != ["time_s", "throughput_mbps"]:
            raise ChannelError(f"{path}:1: header must be 'time_s,throughput_mbps', got {header}")
        for lineno, row in enumerate(reader, start=2):
            if not row or all(not c.strip() for c in row):
                continue
            if len(row) != 2:
                raise ChannelError(f"{path}:{lineno}: expected 2 columns, got {len(row)}")
            try:
                t, v = float(row[0]), float(row[1])
            except ValueError:
                raise ChannelError(f"{path}:{lineno}: not a number: {row}") from None
            if not (math.isfinite(t) and math.isfinite(v)):
                raise ChannelError(f"{path}:{lineno}: NaN or infinite value {row}")
            if v < 0:
                raise ChannelError(f"{path}:{lineno}: negative throughput {v}")
            if times and t <= times[-1]:
                raise ChannelError(f"{path}:{lineno}: time {t} does not increase")
            times.append(t)
            values.append(v)
    if not times:
        raise ChannelError(f"{path}: trace holds no samples")
    return np.array(times), np.array(values)


@dataclass
class TraceChannel:
    """Replays a throughput trace, one slot per ``slot_seconds``, quantised to N states."""

    times: np.ndarray
    throughput: np.ndarray
    rates: np.ndarray
    slot_seconds: float = 2.0
    _slot: int = field(init=False, default=0)
    _levels: np.ndarray = field(init=False, repr=False)

    @classmethod
    def from_csv(cls, path: Path, n_states: int,
                 rate_range: tuple[float, float] = table1.RATE_RANGE_MBPS,
                 slot_seconds: float = 2.0) -> TraceChannel:
        times, values = read_trace(path)
        return cls(times, values, state_rates(n_states, *rate_range), slot_seconds)

    def __post_init__(self) -> None:
        lo, hi = float(self.throughput.min()), float(self.throughput.max())
        span = hi - lo
        scaled = (self.rates[0] + (self.throughput - lo) / span * (self.rates[-1] - self.rates[0])
                  if span > 0 else np.full_like(self.throughput, self.rates.mean()))
        self._levels = scaled

    @property
    def n_states(self) -> int:
        return int(self.rates.size)

    def reset(self, seed: int | None = None) -> None:
        self._slot = 0

    def step(self) -> tuple[int, float]:
        """Mean scaled throughput of the next slot's window (the trace loops at its end)."""
        duration = float(self.times[-1] - self.times[0]) or self.slot_seconds
        start = self.times[0] + (self._slot * self.slot_seconds) % max(duration, self.slot_seconds)
        window = (self.times >= start) & (self.times < start + self.slot_seconds)
        level = float(self._levels[window].mean()) if window.any() else \
            float(np.interp(start, self.times, self._levels))
        self._slot += 1
        state = int(np.argmin(np.abs(self.rates - level)))
        return state, float(self.rates[state])


def parse_channel(spec: str, rate_range: tuple[float, float] = table1.RATE_RANGE_MBPS,
                  seed: int = 0) -> MarkovChannel | TraceChannel:
    """Build a channel from a CLI spec.

    ``markov:N=2[,ratio=0.5][,K=100][,nonstationary][,balanced]`` or ``trace:FILE[,N=4]``;
    ``balanced`` draws doubly stochastic matrices (every state equally often in the long run).
    """
    kind, _, rest = spec.partition(":")
    opts: dict[str, str] = {}
    flags: set[str] = set()
    target = ""
    for i, item in enumerate(filter(None, rest.split(","))):
        if "=" in item:
            key, value = item.split("=", 1)
            opts[key.strip()] = value.strip()
        elif kind == "trace" and i == 0:
            target = item
        else:
            flags.add(item.strip())
    try:
        n = int(opts.get("N", "2"))
        if kind == "markov":
            rates = state_rates(n, *rate_range)
            matrix = two_state_matrix(float(opts["ratio"])) if "ratio" in opts else None
            if matrix is not None and n != 2:
                raise ChannelError("ratio= applies to N=2 only")
            return MarkovChannel(rates, interval_slots=int(opts.get("K", "100")),
                                 stationary="nonstationary" not in flags, matrix=matrix,
                                 balanced="balanced" in flags, seed=seed)
        if kind == "trace":
            if not target:
                raise ChannelError("trace: needs a file, e.g. trace:uplink.csv,N=4")
            return TraceChannel.from_csv(Path(target), n, rate_range)
    except (KeyError, ValueError) as exc:
        if isinstance(exc, ChannelError):
            raise
        raise ChannelError(f"bad channel spec {spec!r}: {exc}") from None
    raise ChannelError(f"unknown channel {kind!r} in {spec!r}; use markov:... or trace:FILE")
