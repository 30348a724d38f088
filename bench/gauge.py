"""A fixed amount of CPU work, timed, printed beside a benchmark's figures.

The development VM's speed drifts by up to ~2× between minutes; a figure is only comparable
with another taken at a similar gauge reading.
"""

from __future__ import annotations

import time

import numpy as np


def python_steps_per_s() -> float:
    """Millions of pure-Python loop steps per second (best of three short runs): the unit
    the simulator benchmark's targets are divided by, so that the machine's phase cancels."""
    best = 0.0
    for _ in range(3):
        t0 = time.perf_counter()
        total = 0
        for i in range(200_000):
            total += i
        best = max(best, 200_000 / (time.perf_counter() - t0))
    return best / 1e6


def cpu_gauge() -> str:
    """'gauge: …' line: millions of pure-Python loop steps and of 64×64 float64 matrix
    products' multiply-adds per second (best of three short runs each)."""
    py, mm = [], []
    a = np.random.default_rng(0).random((64, 64))
    for _ in range(3):
        t0 = time.perf_counter()
        total = 0
        for i in range(200_000):
            total += i
        py.append(200_000 / (time.perf_counter() - t0))
        t0 = time.perf_counter()
        for _ in range(200):
            a @ a
        mm.append(200 * 64**3 / (time.perf_counter() - t0))
    return (f"gauge: {max(py) / 1e6:.1f} M Python loop steps/s, "
            f"{max(mm) / 1e9:.2f} G multiply-adds/s (64×64 matmul)")
