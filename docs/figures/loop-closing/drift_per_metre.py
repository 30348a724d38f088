"""How the error of a long walk grows with the metres walked, with and without loop closing:
per run, the distance every tracked frame is from the truth (after the SE(3) alignment ATE
uses; ATE is their RMS) against the ground truth's path length walked up to that frame.

    .venv/bin/python docs/figures/loop-closing/drift_per_metre.py [--png FILE] [--bin M] \\
        no-loops=docs/figures/loop-closing/corridor-no-loops \\
        loops=docs/figures/loop-closing/corridor-loops

Each ``LABEL=FOLDER`` is a ``twinslam evaluate`` folder of one walk played forward (its
``runs.csv`` and ``calibration_frames.csv[.gz]``); the truth comes from the sequence each run
played (a synthetic walk is rendered again: its poses are exact). Prints two markdown tables
— per label, the walk's length, ATE, ATE per metre walked and the RMS error of each ``--bin``
metres (mean over the runs, with Student's t half-width); and, for the second label against the
first, the paired differences by seed — and with ``--png`` draws the error against the metres
walked (a line a run, the runs' mean bold).
"""

from __future__ import annotations

import argparse
import csv
import math
from collections.abc import Callable
from pathlib import Path

import numpy as np

from twinslam.live.calibration.report import read_rows
from twinslam.reporting import mean_ci95, paired_difference, pyplot
from twinslam.sequences.opening import open_sequence


def walked_m(spec: str, frames: int) -> np.ndarray:
    """The truth's path length (m) from the first frame to each of the first ``frames``."""
    poses = getattr(open_sequence(spec, 0, frames), "poses", None)
    if poses is None or any(p is None for p in poses):
        raise SystemExit(f"{spec}: a walk whose every true pose is known is needed")
    positions = np.array([p[:3, 3] for p in poses])
    return np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(positions, axis=0),
                                                           axis=1))])


class Run:
    """One run's tracked frames: the metres walked to each and its aligned error."""

    def __init__(self, seed: int, ate_m: float, loops: float, walked: np.ndarray,
                 errors: np.ndarray) -> None:
        self.seed, self.ate_m, self.loops = seed, ate_m, loops
        self.walked, self.errors = walked, errors

    @property
    def length_m(self) -> float:
        return float(self.walked.max())

    def rms_in(self, low: float, high: float) -> float:
        inside = self.errors[(self.walked >= low) & (self.walked < high)]
        return float(np.sqrt(np.mean(inside ** 2))) if inside.size else math.nan


def read_runs(folder: Path, sequence: str) -> list[Run]:
    """The runs of one evaluate folder, each with its walk's truth."""
    if not (folder / "runs.csv").is_file():
        raise SystemExit(f"{folder}: no runs.csv (not a twinslam evaluate folder)")
    with (folder / "runs.csv").open(newline="") as fh:
        runs = list(csv.DictReader(fh))
    try:
        frames = read_rows([folder], "calibration_frames.csv")
    except FileNotFoundError as exc:
        raise SystemExit(str(exc)) from None
    out = []
    for run in runs:
        seed = int(run["seed"])
        mine = [r for r in frames if int(r["seed"]) == seed and r["device_tracked"] == "1"
                and r["translation_error_m"] and r["row"] != "-1"]
        rows = np.array([int(r["row"]) for r in mine])
        errors = np.array([float(r["translation_error_m"]) for r in mine])
        count = int(rows.max()) + 1 if rows.size else 0
        name, _, rest = sequence.partition(":")
        spec = f"{name}:{rest.partition(':')[0]}:{seed}" if rest else sequence
        path = walked_m(spec, count)
        out.append(Run(seed, float(run["ate_m"]), float(run.get("loops_closed") or 0),
                       path[rows], errors))
    return sorted(out, key=lambda r: r.seed)


def bins(variants: dict[str, list[Run]], bin_m: float) -> list[tuple[float, float]]:
    """(from, to) metres of each bin over the longest run; a remainder shorter than a quarter
    bin joins the last bin (a walk of 85.5 m in bins of 21 m has four, not a fifth of 1.5 m)."""
    longest = max(r.length_m for runs in variants.values() for r in runs)
    starts = list(np.arange(0.0, longest, bin_m))
    if len(starts) > 1 and longest - starts[-1] < bin_m / 4:
        starts.pop()
    return [(float(a), float(b)) for a, b in zip(starts, [*starts[1:], math.inf], strict=True)]


def paired(pairs: list[tuple[Run, Run]], measure: Callable[[Run], float], digits: int) -> str:
    """The paired difference (variant − baseline) of one measure over seeds, with its CI."""
    d = paired_difference([[measure(a) for a, _ in pairs]], [measure(b) for _, b in pairs])
    return f"{d.mean:.{digits}f} [{d.low:.{digits}f}, {d.high:.{digits}f}]"


def tables(variants: dict[str, list[Run]], bin_m: float) -> str:
    """Markdown: per variant the mean figures; then each variant against the first."""
    edges = bins(variants, bin_m)
    head = ["variant", "runs", "walked (m)", "loops closed", "ATE (m)", "ATE per metre (mm/m)",
            *[f"{a:.0f}–{b:.0f} m" if b < math.inf else f"{a:.0f} m–end" for a, b in edges]]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]

    def cell(values: list[float], scale: float = 1.0, digits: int = 3) -> str:
        mean, half = mean_ci95([v * scale for v in values])
        if math.isnan(mean):
            return "–"
        return f"{mean:.{digits}f}" + ("" if math.isnan(half) else f" ± {half:.{digits}f}")

    for label, runs in variants.items():
        lines.append("| " + " | ".join([
            label, str(len(runs)), cell([r.length_m for r in runs], digits=1),
            cell([r.loops for r in runs], digits=1), cell([r.ate_m for r in runs]),
            cell([r.ate_m / r.length_m for r in runs], 1e3, 2),
            *[cell([r.rms_in(a, b) for r in runs]) for a, b in edges]]) + " |")
    labels = list(variants)
    if len(labels) > 1:
        base = {r.seed: r for r in variants[labels[0]]}
        last = edges[-1]

        def last_bin(run: Run) -> float:
            return run.rms_in(*last)

        lines += ["", f"| variant − {labels[0]}, paired by seed | seeds | ATE (m) | "
                  "ATE per metre (mm/m) | the last bin (m) |", "|---|---|---|---|---|"]
        for label in labels[1:]:
            pairs = [(r, base[r.seed]) for r in variants[label] if r.seed in base]
            if not pairs:
                continue
            figures = [paired(pairs, lambda r: r.ate_m, 3),
                       paired(pairs, lambda r: 1e3 * r.ate_m / r.length_m, 2),
                       paired(pairs, last_bin, 3)]
            lines.append(f"| {label} | {len(pairs)} | " + " | ".join(figures) + " |")
    return "\n".join(lines)


def draw(variants: dict[str, list[Run]], bin_m: float, png: Path) -> None:
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(10, 4.5))
    colours = plt.get_cmap("tab10")
    edges = bins(variants, bin_m)
    longest = max(r.length_m for runs in variants.values() for r in runs)
    middles = np.array([(a + min(b, longest)) / 2 for a, b in edges])
    for i, (label, runs) in enumerate(variants.items()):
        curves = np.array([[100 * r.rms_in(a, b) for a, b in edges] for r in runs])
        for curve in curves:
            ax.plot(middles, curve, color=colours(i), alpha=0.3, linewidth=0.8)
        ax.plot(middles, np.nanmean(curves, axis=0), color=colours(i), linewidth=2,
                marker="o", markersize=3, label=f"{label} ({len(runs)} runs)")
    ax.set_xlabel("metres walked (ground truth)")
    ax.set_ylabel(f"RMS position error over {bin_m:g} m (cm)")
    ax.set_title("The error along a long walk, SE(3)-aligned, tracked frames")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(png, dpi=120)
    plt.close(fig)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("inputs", nargs="+", metavar="LABEL=FOLDER",
                        help="a twinslam evaluate folder of a walk played forward; the first "
                             "is the baseline of the paired differences")
    parser.add_argument("--sequence", default="synthetic-corridor:5400",
                        help="the sequence the runs played (a synthetic one: each seed's own "
                             "walk); default synthetic-corridor:5400")
    parser.add_argument("--bin", type=float, default=21.0,
                        help="metres walked a bin (default 21: one length of the corridor)")
    parser.add_argument("--png", type=Path, default=None, help="draw the curves here")
    args = parser.parse_args()
    if args.bin <= 0:
        parser.error(f"--bin must be positive, got {args.bin}")
    variants: dict[str, list[Run]] = {}
    for item in args.inputs:
        label, sep, path = item.partition("=")
        if not sep or not label or not path:
            parser.error(f"expected LABEL=FOLDER, got {item!r}")
        variants[label] = read_runs(Path(path), args.sequence)
    print(tables(variants, args.bin))
    if args.png is not None:
        draw(variants, args.bin, args.png)
        print(f"wrote {args.png}")


if __name__ == "__main__":
    main()
