"""The tables of docs/results/restores.md, "The edge's archive and restores", from the
runs.csv of two
``twinslam evaluate`` folders that differ only in the edge's ``restore_keyframes`` (the same
scenario, map source, policies and seeds):

    .venv/bin/python docs/figures/archive_restores.py \\
        docs/figures/archive-restores/revisit-v15-lff-restore0-runs.csv \\
        docs/figures/archive-restores/revisit-v15-lff-restore3-runs.csv

One row per policy and seed (untracked frames; the edge's mean υ, lost share and υ over the
tracked frames; ATE; the keyframes restored where the file counts them), then per policy the
paired difference, restores minus none, mean [95 % CI] over the seeds
(twinslam.reporting.paired_difference, Student's t over seeds). A run whose device dropped
camera frames is refused: it measures the machine.
"""

from __future__ import annotations

import csv
import math
import sys
from pathlib import Path

import numpy as np

from twinslam.reporting import paired_difference

METRICS = (("untracked_frames", "untracked frames", "{:.0f}"),
           ("mean_uncertainty", "mean υ", "{:.1f}"), ("lost_share", "lost share", "{:.3f}"),
           ("tracked_uncertainty", "υ tracked", "{:.1f}"), ("ate_m", "ATE (m)", "{:.3f}"))
#: counted by runs.csv files since the restores were (older files: the column is left out)
RESTORES = "restores"


def _runs(path: Path) -> dict[tuple[str, int], dict[str, str]]:
    """(policy, seed) → the run's row."""
    with path.open(encoding="utf-8") as fh:
        rows = {(r["policy"], int(r["seed"])): r for r in csv.DictReader(fh)}
    dropped = [key for key, r in rows.items() if int(r["frames_dropped"] or 0)]
    if dropped:
        raise SystemExit(f"{path}: runs {dropped} dropped camera frames; rerun with fewer jobs")
    return rows


def _restored(row: dict[str, str]) -> str:
    value = float(row.get(RESTORES) or math.nan)
    return "–" if math.isnan(value) else f"{value:.0f}"


def main(without: Path, with_restores: Path) -> None:
    off, on = _runs(without), _runs(with_restores)
    if sorted(on) != sorted(off):
        raise SystemExit("the two folders hold different policies or seeds: no pairing")
    counted = all(RESTORES in r for r in on.values())
    print("| policy | seed | " + " | ".join(f"{label}, none / restores"
                                           for _, label, _ in METRICS)
          + (" | keyframes restored |" if counted else " |"))
    print("|---|---|" + "---|" * (len(METRICS) + counted))
    policies = list(dict.fromkeys(policy for policy, _ in sorted(off)))
    for policy in policies:
        seeds = sorted(s for p, s in off if p == policy)
        for s in seeds:
            a, b = off[policy, s], on[policy, s]
            cells = [f"{fmt.format(float(a[k]))} / {fmt.format(float(b[k]))}"
                     for k, _, fmt in METRICS] + ([_restored(b)] if counted else [])
            print(f"| {policy} | {s} | " + " | ".join(cells) + " |")
        cells = []
        for k, _, fmt in METRICS:
            d = paired_difference(np.array([[float(on[policy, s][k]) for s in seeds]]),
                                  [float(off[policy, s][k]) for s in seeds])
            cells.append(f"{fmt.format(d.mean)} [{fmt.format(d.low)}, {fmt.format(d.high)}]")
        print(f"| {policy} | paired, restores − none | " + " | ".join(cells)
              + (" | |" if counted else " |"))


if __name__ == "__main__":
    if len(sys.argv) != 3:
        raise SystemExit(__doc__)
    main(Path(sys.argv[1]), Path(sys.argv[2]))
