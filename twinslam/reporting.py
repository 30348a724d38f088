"""Writing experiment results: one CSV per figure, means with confidence intervals, and a
headless matplotlib."""

from __future__ import annotations

import csv
import math
from collections.abc import Sequence
from pathlib import Path
from types import ModuleType

import numpy as np


def file_name(text: str, allowed: str = "+-_.", filler: str = "-") -> str:
    """``text`` as a file name: letters, digits and ``allowed`` kept, anything else (a path's
    slash, a policy's colon) replaced by ``filler``."""
    return "".join(c if c.isalnum() or c in allowed else filler for c in text)


def write_csv(path: Path, header: Sequence[str], rows: Sequence[Sequence[object]]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w", newline="", encoding="utf-8") as fh:
        writer = csv.writer(fh)
        writer.writerow(header)
        writer.writerows(rows)


def pyplot() -> ModuleType:
    """``matplotlib.pyplot`` on the Agg backend (no display on CI machines or edge hosts)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def pearson_r(x: np.ndarray, y: np.ndarray) -> float:
    """Pearson's r of paired values; NaN below 3 pairs or with a constant side (r is then
    undefined, not 0: a device that never failed neither agrees nor disagrees)."""
    x, y = np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64)
    if x.size < 3 or np.ptp(x) == 0 or np.ptp(y) == 0:
        return math.nan
    return float(np.corrcoef(x, y)[0, 1])


def mean_ci95(values: list[float]) -> tuple[float, float]:
    """Mean and 95 % confidence half-width (Student t) of independent runs; NaN values (a
    metric a run could not measure) are left out, and the half-width is NaN under two runs."""
    x = np.asarray([v for v in values if not math.isnan(v)], dtype=np.float64)
    if x.size == 0:
        return math.nan, math.nan
    if x.size < 2:
        return float(x.mean()), math.nan
    # scipy.stats takes 0.4 s to import: loaded only where a CI is computed
    from scipy import stats

    half = stats.t.ppf(0.975, x.size - 1) * x.std(ddof=1) / math.sqrt(x.size)
    return float(x.mean()), float(half)
