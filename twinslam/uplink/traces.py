"""Uplink throughput traces: reading the common CSV spellings, writing, and generating some.

A trace is a time series of measured throughput. Tools export it with many headers, so the
reader takes the first column that names a time (``time``, ``time_s``, ``t``, ``timestamp``,
``seconds``, ``elapsed``; ``_ms`` for milliseconds) and the first that names a rate
(``throughput``, ``rate``, ``bandwidth``, ``bw``, ``bitrate``, ``capacity``, ``tput``,
``mbps``…; unit ``mbps``/``mbit/s`` (also when none is given), ``kbps``/``kbit/s``, ``gbps``,
``bps``/``bit/s``). A sample holds its rate until the next one: a slot's rate is the mean of
that step function over the slot.

No third-party trace is bundled; :func:`generate_trace` makes traces with regime changes and
outages for tests and experiments (``twinslam trace``).
"""

from __future__ import annotations

import csv
import math
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from twinslam.uplink.errors import ChannelError

TIME_NAMES = ("time", "t", "timestamp", "seconds", "sec", "elapsed")
RATE_NAMES = ("throughput", "rate", "bandwidth", "bw", "bitrate", "capacity", "tput", "uplink",
              "downlink", "mbps", "kbps", "gbps", "bps")
#: Mbit/s per unit, by the unit's spelling in a header
RATE_UNITS = {"mbps": 1.0, "mbit": 1.0, "mbits": 1.0, "kbps": 1e-3, "kbit": 1e-3,
              "kbits": 1e-3, "gbps": 1e3, "gbit": 1e3, "bps": 1e-6, "bit": 1e-6, "bits": 1e-6}


class TraceError(ChannelError):
    """A trace file that cannot be read as time + throughput; names the file and line."""


def _tokens(header: str) -> list[str]:
    return [t for t in re.split(r"[\s_()\[\]/,.-]+", header.strip().lower()) if t]


def _time_scale(tokens: list[str]) -> float | None:
    if not tokens or tokens[0] not in TIME_NAMES:
        return None
    return 1e-3 if "ms" in tokens or "millis" in tokens else 1.0


def _rate_scale(tokens: list[str]) -> float | None:
    if not tokens or tokens[0] not in RATE_NAMES:
        return None
    for token in tokens:
        if token in RATE_UNITS:
            return RATE_UNITS[token]
    return 1.0                                        # no unit: Mbit/s


def _columns(path: Path, header: list[str]) -> tuple[int, float, int, float]:
    """(time column, seconds per unit, rate column, Mbit/s per unit) from a header row."""
    times = [(i, s) for i, h in enumerate(header) if (s := _time_scale(_tokens(h))) is not None]
    rates = [(i, s) for i, h in enumerate(header) if (s := _rate_scale(_tokens(h))) is not None
             and i not in {j for j, _ in times}]
    if not times or not rates:
        raise TraceError(
            f"{path}:1: header {header} names no {'time' if not times else 'throughput'} "
            f"column; use e.g. 'time_s,throughput_mbps' (time: {', '.join(TIME_NAMES)}, "
            f"optionally _ms; throughput: {', '.join(RATE_NAMES)}, optionally with a unit "
            "mbps, kbps, gbps or bps)")
    return times[0][0], times[0][1], rates[0][0], rates[0][1]


def read_trace(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """(times in s, throughput in Mbit/s) of a CSV trace; bad rows refused naming the line."""
    path = Path(path)
    if not path.is_file():
        raise TraceError(f"trace file {path} does not exist")
    times: list[float] = []
    values: list[float] = []
    with path.open(newline="", encoding="utf-8") as fh:
        reader = csv.reader(fh)
        header = next(reader, None)
        if header is None:
            raise TraceError(f"{path}: empty trace file")
        t_col, t_scale, r_col, r_scale = _columns(path, header)
        for lineno, row in enumerate(reader, start=2):
            if not row or all(not c.strip() for c in row):
                continue
            if len(row) <= max(t_col, r_col):
                raise TraceError(f"{path}:{lineno}: expected {len(header)} columns, got "
                                 f"{len(row)}")
            try:
                t, v = float(row[t_col]) * t_scale, float(row[r_col]) * r_scale
            except ValueError:
                raise TraceError(f"{path}:{lineno}: not a number: {row}") from None
            if not (math.isfinite(t) and math.isfinite(v)):
                raise TraceError(f"{path}:{lineno}: NaN or infinite value {row}")
            if v < 0:
                raise TraceError(f"{path}:{lineno}: negative throughput {v}")
            if times and t <= times[-1]:
                raise TraceError(f"{path}:{lineno}: time {t} does not increase")
            times.append(t)
            values.append(v)
    if len(times) < 2:
        raise TraceError(f"{path}: a trace needs at least two samples, got {len(times)}")
    return np.array(times), np.array(values)


def write_trace(path: Path, times: np.ndarray, mbps: np.ndarray) -> None:
    """``time_s,throughput_mbps`` CSV, the spelling the reader tries first (its folder made
    if missing)."""
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    with Path(path).open("w", newline="", encoding="utf-8") as fh:
        writer = csv.writer(fh)
        writer.writerow(["time_s", "throughput_mbps"])
        writer.writerows([f"{t:.3f}", f"{v:.4f}"] for t, v in zip(times, mbps, strict=True))


@dataclass(frozen=True)
class TraceShape:
    """What :func:`generate_trace` draws: regimes of a random mean rate, noise around it, and
    outages (0 Mbit/s)."""

    seconds: float = 600.0
    sample_s: float = 0.1               #: one throughput sample per this many seconds
    rate_range: tuple[float, float] = (5.0, 80.0)   #: regime means lie in here (Mbit/s)
    regime_s: float = 60.0              #: mean regime length (exponential)
    noise: float = 0.15                 #: relative std of the samples around a regime's mean
    outages: tuple[tuple[float, float], ...] = ()   #: (start s, duration s), always placed
    outage_every_s: float = 0.0         #: also random outages, one per this many s on average
    outage_s: float = 5.0               #: mean duration of a random outage (exponential)
    #: or a random outage lasts between these many seconds (uniform): a mmWave blockage
    outage_range_s: tuple[float, float] | None = None


def generate_trace(shape: TraceShape, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """(times, Mbit/s) of a synthetic trace with regime changes and outages."""
    if shape.seconds <= 0 or shape.sample_s <= 0 or shape.regime_s <= 0:
        raise ValueError("seconds, sample_s and regime_s must be > 0")
    lo, hi = shape.rate_range
    if not 0 <= lo <= hi:
        raise ValueError(f"rate range must satisfy 0 <= min <= max, got {lo}, {hi}")
    rng = np.random.default_rng(seed)
    times = np.arange(0.0, shape.seconds, shape.sample_s)
    means = np.empty_like(times)
    t = 0.0
    while t < shape.seconds:
        length = rng.exponential(shape.regime_s)
        means[(times >= t) & (times < t + length)] = rng.uniform(lo, hi)
        t += length
    mbps = np.clip(means * (1 + shape.noise * rng.standard_normal(times.size)), 0.0, None)
    outages = list(shape.outages)
    if shape.outage_every_s > 0:
        t = rng.exponential(shape.outage_every_s)
        while t < shape.seconds:
            if shape.outage_range_s:            # a blockage: the next starts after it ends
                length = rng.uniform(*shape.outage_range_s)
                outages.append((t, length))
                t += length + rng.exponential(shape.outage_every_s)
            else:                               # (these may overlap, as they always did)
                outages.append((t, rng.exponential(shape.outage_s)))
                t += rng.exponential(shape.outage_every_s)
    for start, duration in outages:
        mbps[(times >= start) & (times < start + duration)] = 0.0
    return times, mbps
