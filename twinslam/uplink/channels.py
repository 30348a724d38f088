"""Uplink channel models: the rate d_k of every slot (paper §III-C).

Inside an interval of K slots the rate follows an N-state Markov chain with one transition
matrix; across intervals the matrix may change (the hidden x_t). ``MarkovChannel`` generates
such rates, stationary (one matrix for all intervals) or non-stationary (a new matrix drawn per
interval). ``TraceChannel`` replays a measured throughput trace instead: the slot's real mean
Mbit/s (an outage is 0: nothing uploads), its state from a :class:`RateQuantiser`, each seed
starting at its own offset into the trace. File formats: :mod:`twinslam.uplink.traces`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from twinslam.slot_protocol import table1
from twinslam.uplink.errors import ChannelError
from twinslam.uplink.quantiser import RateQuantiser
from twinslam.uplink.traces import TraceShape, generate_trace, read_trace

__all__ = ["ChannelError", "MarkovChannel", "TraceChannel", "parse_channel", "state_rates"]

#: seconds one slot lasts at the paper's sizes (F frames at the camera's rate)
SLOT_SECONDS = table1.SLOT_FRAMES / table1.FRAME_RATE_HZ


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


def chain_states(matrices: list[np.ndarray], interval_slots: int,
                 rng: np.random.Generator) -> np.ndarray:
    """States of a chain that follows ``matrices[t]`` during interval t (a drifting channel:
    the twin experiments' ground truth)."""
    n = matrices[0].shape[0]
    out = np.empty(len(matrices) * interval_slots, dtype=np.int64)
    state = int(rng.integers(n))
    for t, m in enumerate(matrices):
        cum = m.cumsum(axis=1)
        for k in range(interval_slots):
            state = min(int((rng.random() > cum[state]).sum()), n - 1)
            out[t * interval_slots + k] = state
    return out


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


@dataclass
class TraceChannel:
    """Replays a throughput trace one slot (``slot_seconds``) at a time.

    ``step`` gives the slot's mean real Mbit/s — the step function of the samples averaged over
    the slot, the trace looping at its end — and its state from ``quantiser``. ``rescale``
    (explicit only) maps the trace's min..max linearly onto a range first, the way the first
    versions replayed every trace. ``reset(seed)`` starts at ``start_s`` if given, else at an
    offset drawn from the seed, so seeds replay different stretches of one trace.
    """

    times: np.ndarray
    throughput: np.ndarray                    #: Mbit/s, as measured
    quantiser: RateQuantiser
    slot_seconds: float = SLOT_SECONDS
    rescale: tuple[float, float] | None = None
    start_s: float | None = None
    seed: int = 0
    _offset: float = field(init=False, default=0.0)
    _slot: int = field(init=False, default=0)
    _cumulative: np.ndarray = field(init=False, repr=False)
    _period: float = field(init=False, default=0.0)
    _edges: np.ndarray = field(init=False, repr=False)

    @classmethod
    def from_csv(cls, path: Path, n_states: int, quantise_range: tuple[float, float] | None = None,
                 slot_seconds: float = SLOT_SECONDS, rescale: tuple[float, float] | None = None,
                 start_s: float | None = None, seed: int = 0) -> TraceChannel:
        """A trace file's channel; states over ``quantise_range`` (evenly) or, by default, the
        trace's own quantiles of its per-slot rates."""
        times, values = read_trace(path)
        return cls.from_samples(times, values, n_states, quantise_range, slot_seconds, rescale,
                                start_s, seed)

    @classmethod
    def from_samples(cls, times: np.ndarray, throughput: np.ndarray, n_states: int,
                     quantise_range: tuple[float, float] | None = None,
                     slot_seconds: float = SLOT_SECONDS,
                     rescale: tuple[float, float] | None = None, start_s: float | None = None,
                     seed: int = 0) -> TraceChannel:
        """The channel of throughput samples (e.g. a generated trace), quantised as
        :meth:`from_csv` does."""
        channel = cls(times, throughput, RateQuantiser.evenly(1, 0.0, 1.0), slot_seconds,
                      rescale, start_s, seed)
        channel.quantiser = (RateQuantiser.evenly(n_states, *quantise_range) if quantise_range
                             else RateQuantiser.from_quantiles(channel.slot_rates(), n_states))
        return channel

    def __post_init__(self) -> None:
        self._load(self.times, self.throughput)
        self.reset(self.seed)

    def _load(self, times: np.ndarray, throughput: np.ndarray) -> None:
        """Take ``times`` / ``throughput`` as the trace to replay (checked, rescaled)."""
        t = np.asarray(times, dtype=np.float64)
        v = np.asarray(throughput, dtype=np.float64)
        if t.ndim != 1 or t.shape != v.shape or t.size < 2 or np.any(np.diff(t) <= 0):
            raise ChannelError("a trace needs >= 2 samples at strictly increasing times")
        if not self.slot_seconds > 0:
            raise ChannelError(f"slot length must be > 0 s, got {self.slot_seconds}")
        if self.rescale is not None:
            lo, hi = self.rescale
            span = float(v.max() - v.min())
            v = (lo + (v - v.min()) / span * (hi - lo) if span > 0
                 else np.full_like(v, (lo + hi) / 2))
        self.times, self.throughput = t, v
        # each sample holds until the next; the last for the median sample spacing
        held = np.diff(t, append=t[-1] + float(np.median(np.diff(t))))
        self._period = float(held.sum())
        self._cumulative = np.concatenate([[0.0], np.cumsum(v * held)])
        self._edges = np.concatenate([t - t[0], [self._period]])

    @property
    def n_states(self) -> int:
        return self.quantiser.n_states

    @property
    def rates(self) -> np.ndarray:
        """The representative Mbit/s of each state (for emulated rates and initial shaping)."""
        return self.quantiser.rates

    @property
    def duration_s(self) -> float:
        return self._period

    def _integral(self, t: float) -> float:
        """∫ rate dt (Mbit) from the trace's start to ``t`` s after it, looping."""
        laps, rest = divmod(t, self._period)
        return laps * float(self._cumulative[-1]) + float(
            np.interp(rest, self._edges, self._cumulative))

    def rate_over(self, start: float, seconds: float) -> float:
        """Mean Mbit/s from ``start`` s into the trace for ``seconds`` (rounded to 1e-9 so that
        a constant trace gives its constant back, not 39.99999999999977)."""
        return round((self._integral(start + seconds) - self._integral(start)) / seconds, 9)

    def slot_rates(self) -> np.ndarray:
        """The mean rate of every whole slot of one pass through the trace from its start."""
        n = max(1, int(self._period // self.slot_seconds))
        return np.array([self.rate_over(i * self.slot_seconds, self.slot_seconds)
                         for i in range(n)])

    def reset(self, seed: int | None = None) -> None:
        self._slot = 0
        if self.start_s is not None:
            self._offset = float(self.start_s)
        else:
            rng = np.random.default_rng(self.seed if seed is None else seed)
            self._offset = float(rng.uniform(0.0, self._period))

    def step(self) -> tuple[int, float]:
        """(state, real mean Mbit/s) of the next slot."""
        rate = self.rate_over(self._offset + self._slot * self.slot_seconds, self.slot_seconds)
        self._slot += 1
        return self.quantiser.state(rate), rate


def initial_rate(channel: MarkovChannel | TraceChannel) -> float:
    """A positive Mbit/s to shape with before the first slot's rate is known: the lowest
    positive state rate (a trace's lowest state may be an outage)."""
    positive = [float(r) for r in channel.rates if r > 0]
    return min(positive) if positive else table1.RATE_MIN_MBPS


def _pair(text: str, what: str) -> tuple[float, float]:
    lo, sep, hi = text.partition("-")
    if not sep:
        raise ChannelError(f"{what} takes MIN-MAX in Mbit/s, got {text!r}")
    return float(lo), float(hi)


def parse_channel(spec: str, rate_range: tuple[float, float] = table1.RATE_RANGE_MBPS,
                  seed: int = 0, slot_seconds: float = SLOT_SECONDS
                  ) -> MarkovChannel | TraceChannel:
    """Build a channel from a CLI spec.

    ``markov:N=2[,ratio=0.5][,K=100][,nonstationary][,balanced]``: N rates evenly over
    ``rate_range``; ``balanced`` draws doubly stochastic matrices (every state equally often).

    ``trace:FILE[,N=4][,states=MIN-MAX][,rescale][,start=S][,slot=S]``: the trace's real Mbit/s
    (an outage uploads nothing); states by the trace's quantiles, or evenly over
    ``states=MIN-MAX``; ``rescale`` maps the trace's min..max onto ``rate_range`` first;
    ``start=S`` fixes where every seed starts (default: an offset per seed); ``slot=S`` the slot
    length (default ``slot_seconds``: the slots of whoever steps the channel — Table I's F /
    frame rate = 2 s unless given; a device with shorter slots must say so, or each of its
    slots would replay a 2 s stretch of the trace, the trace at more than its real speed).

    ``generated[:regime=S][,outage_every=S][,outage=S][,range=MIN-MAX][,noise=X][,seconds=S]
    [,N=4]``: a trace drawn from ``seed`` (:func:`~twinslam.uplink.traces.generate_trace`) and
    replayed from its start at its real Mbit/s like a trace file: regimes of random mean rate in
    ``range`` lasting ~``regime`` s, an outage (0 Mbit/s) of ~``outage`` s (exponential; or
    ``outage=MIN-MAX``: uniform between, a blockage) every ~``outage_every`` s (0: none).
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
            unknown = flags - {"rescale"} or set(opts) - {"N", "states", "start", "slot"}
            if unknown:
                raise ChannelError(f"trace: unknown option(s) {sorted(unknown)}; use N=, "
                                   "states=MIN-MAX, rescale, start=S, slot=S")
            return TraceChannel.from_csv(
                Path(target), n,
                _pair(opts["states"], "states=") if "states" in opts else None,
                float(opts.get("slot", slot_seconds)),
                rate_range if "rescale" in flags else None,
                float(opts["start"]) if "start" in opts else None, seed)
    except (KeyError, ValueError) as exc:
        if isinstance(exc, ChannelError):
            raise
        raise ChannelError(f"bad channel spec {spec!r}: {exc}") from None
    if kind == "generated":
        return _generated(spec, opts, flags, seed, slot_seconds)
    raise ChannelError(f"unknown channel {kind!r} in {spec!r}; use markov:..., trace:FILE or "
                       "generated:...")


@dataclass
class GeneratedChannel(TraceChannel):
    """A trace drawn from a seed (:func:`~twinslam.uplink.traces.generate_trace`) and replayed
    from its start: ``reset(seed)`` draws that seed's trace, so a sweep over seeds replays a
    different trace each, and a simulator episode of seed s replays the device's of seed s.
    States by the quantiles of the drawn trace's slot rates."""

    shape: TraceShape = field(default_factory=TraceShape)
    levels: int = 2                           #: N states
    _drawn: int | None = field(init=False, default=None)

    @classmethod
    def draw(cls, shape: TraceShape, levels: int, seed: int = 0,
             slot_seconds: float = SLOT_SECONDS) -> GeneratedChannel:
        times, mbps = generate_trace(shape, seed)
        return cls(times, mbps, RateQuantiser.evenly(1, 0.0, 1.0), slot_seconds, start_s=0.0,
                   seed=seed, shape=shape, levels=levels)

    def reset(self, seed: int | None = None) -> None:
        seed = self.seed if seed is None else seed
        if seed != self._drawn:
            self._drawn = seed
            self._load(*generate_trace(self.shape, seed))
            self.quantiser = RateQuantiser.from_quantiles(self.slot_rates(), self.levels)
        super().reset(seed)


def _generated(spec: str, opts: dict[str, str], flags: set[str], seed: int,
               slot_seconds: float = SLOT_SECONDS) -> TraceChannel:
    """The ``generated:...`` channel of :func:`parse_channel`."""
    known = {"regime", "outage_every", "outage", "range", "noise", "seconds", "N"}
    if flags or set(opts) - known:
        raise ChannelError(f"generated: unknown option(s) {sorted(flags | set(opts) - known)} "
                           f"in {spec!r}; use " + ", ".join(f"{k}=" for k in sorted(known)))
    default = TraceShape()
    try:
        shape = TraceShape(
            seconds=float(opts.get("seconds", 3600.0)),
            rate_range=(_pair(opts["range"], "range=") if "range" in opts
                        else default.rate_range),
            regime_s=float(opts.get("regime", default.regime_s)),
            noise=float(opts.get("noise", default.noise)),
            outage_every_s=float(opts.get("outage_every", 0.0)),
            outage_s=(default.outage_s if "-" in opts.get("outage", "")
                      else float(opts.get("outage", default.outage_s))),
            outage_range_s=(_pair(opts["outage"], "outage=") if "-" in opts.get("outage", "")
                            else None))
        if shape.outage_every_s < 0 or shape.outage_s <= 0 or shape.noise < 0:
            raise ValueError("outage_every must be >= 0, outage > 0 and noise >= 0")
        if shape.outage_range_s and not 0 < shape.outage_range_s[0] <= shape.outage_range_s[1]:
            raise ValueError("outage=MIN-MAX needs 0 < MIN <= MAX")
        return GeneratedChannel.draw(shape, int(opts.get("N", "2")), seed, slot_seconds)
    except ValueError as exc:
        if isinstance(exc, ChannelError):
            raise
        raise ChannelError(f"bad channel spec {spec!r}: {exc}") from None
