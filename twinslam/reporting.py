"""Writing experiment results: one CSV per figure, means with confidence intervals, paired
differences, and a headless matplotlib.

Every table's interval comes from here: :func:`mean_ci95` (Student's t over independent
runs) and :func:`paired_difference` (the same t over the differences of runs paired by seed
or episode; a two-level bootstrap only where a learned variant adds training runs on top of
the episodes)."""

from __future__ import annotations

import csv
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from types import ModuleType
from typing import Any

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


def write_dict_rows(path: Path, rows: Sequence[Mapping[str, object]]) -> None:
    """Rows of one shape (the same keys, in order) as a table at ``path``, their keys the
    header: what a bench writes with ``--csv``."""
    if not rows:
        raise ValueError(f"{path}: no rows to write")
    header = list(rows[0])
    write_csv(Path(path), header, [[r[k] for k in header] for r in rows])


def append_csv_rows(path: Path, columns: Sequence[str],
                    rows: Sequence[Mapping[str, object]]) -> None:
    """Append ``rows`` (column → value; a column they lack is left empty) to the table at
    ``path`` under ``columns``, its header written first when the file is new. A table an
    older version wrote under other columns is rewritten under both (its own first, then
    the new ones), every row it held kept: a run appended to last month's file loses
    nothing and lands under the right heads."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    header, kept = list(columns), []
    if path.exists() and path.stat().st_size:
        with path.open(newline="", encoding="utf-8") as fh:
            reader = csv.DictReader(fh)
            have = list(reader.fieldnames or [])
            if have != header:
                kept = list(reader)
                header = have + [c for c in columns if c not in have]
            else:
                header = []                   # the same heads: append below them
    with path.open("a" if not header else "w", newline="", encoding="utf-8") as fh:
        writer = csv.DictWriter(fh, fieldnames=header or list(columns), restval="")
        if header:
            writer.writeheader()
            writer.writerows(kept)
        writer.writerows({c: row.get(c, "") for c in columns} for row in rows)


def pyplot() -> ModuleType:
    """``matplotlib.pyplot`` on the Agg backend (no display on CI machines or edge hosts)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def seed_lines(ax: Any, seeds: Sequence[int], before: Sequence[float],
               after: Sequence[float], arms: tuple[str, str] = ("before", "after")) -> None:
    """A paired comparison on a matplotlib axes ``ax`` (typed loosely, as matplotlib is
    imported only where a figure is drawn): one line a seed from its ``before`` value to its
    ``after`` one (blue where after is no higher, red where it is), each line's end named by
    its seed, the two arms named on the x axis. A paired table's CI says whether a change
    moved a figure; these lines say whether every seed moved it, or one seed did."""
    for seed, old, new in zip(seeds, before, after, strict=True):
        ax.plot([0, 1], [old, new], marker="o", color="tab:blue" if new <= old else "tab:red",
                alpha=0.8)
        ax.annotate(str(seed), (1.03, new), fontsize=7, va="center")
    ax.set_xticks([0, 1], list(arms))
    ax.set_xlim(-0.3, 1.3)


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


@dataclass(frozen=True)
class PairedDifference:
    """Mean of (policy − baseline) over paired runs, and its 95 % interval."""

    mean: float
    low: float
    high: float

    @property
    def apart(self) -> bool:
        """Whether the interval excludes 0: the two are told apart."""
        return self.low > 0 or self.high < 0


def paired_difference(scores: np.ndarray | Sequence[Sequence[float]],
                      baseline: np.ndarray | Sequence[float], draws: int = 2000,
                      seed: int = 0) -> PairedDifference:
    """The one paired difference of the project's tables. ``scores``: R runs × E episodes
    (or seeds) of a variant; ``baseline``: the E episodes of what it is compared with, in the
    same order — or R × E, each run against its own baseline (a trained actor against the
    same run's untrained one).

    One run (a rule, a device variant: R = 1) gets Student's t over its E paired differences,
    as :func:`mean_ci95` (NaN pairs left out; a constant gap has an interval of width 0). A
    learned variant's R training runs on the same E episodes have two sources of spread —
    which run, which episode — and neither the run means alone nor the R × E cells taken as
    independent count both: there the interval comes from a two-level bootstrap (runs drawn
    with replacement, then episodes), reproducible through ``seed``."""
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
    if runs == 1:
        mean, half = mean_ci95(diff[0].tolist())
        return PairedDifference(mean, mean - half, mean + half)
    rng = np.random.default_rng(seed)
    r = rng.integers(0, runs, size=(draws, runs))
    e = rng.integers(0, episodes, size=(draws, episodes))
    means = np.array([diff[np.ix_(r[b], e[b])].mean() for b in range(draws)])
    low, high = np.percentile(means, [2.5, 97.5])
    return PairedDifference(float(diff.mean()), float(low), float(high))


def paired_row(label: str, before: Sequence[float], after: Sequence[float],
               fmt: str = "{:.1f}") -> str:
    """A markdown row of the results pages' paired tables: the label, each arm run by run
    (``fmt``) and after − before with its 95 % interval (:func:`paired_difference`)."""
    d = paired_difference([list(after)], list(before))
    return (f"| {label} | {', '.join(fmt.format(x) for x in before)} | "
            f"{', '.join(fmt.format(x) for x in after)} | "
            f"{d.mean:+.2f} [{d.low:+.2f}, {d.high:+.2f}] |")
