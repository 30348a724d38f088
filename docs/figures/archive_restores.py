"""The table of docs/results.md, "The edge's archive and restores: a first live look", from
the runs.csv of two ``twinslam evaluate`` folders that differ only in the edge's
``restore_keyframes`` (the same scenario, map source, policy and seeds):

    .venv/bin/python docs/figures/archive_restores.py \\
        docs/figures/archive-restores/revisit-v15-lff-restore0-runs.csv \\
        docs/figures/archive-restores/revisit-v15-lff-restore3-runs.csv

One row per seed (untracked frames; the edge's mean υ, lost share and υ over the tracked
frames; ATE), then the paired difference, restores minus none, mean [95 % CI] over the seeds
(twinslam.experiments.paired, bootstrap over seeds). A run whose device dropped camera frames
is refused: it measures the machine.
"""

from __future__ import annotations

import csv
import sys
from pathlib import Path

import numpy as np

from twinslam.experiments.paired import paired_difference

METRICS = (("untracked_frames", "untracked frames", "{:.0f}"),
           ("mean_uncertainty", "mean υ", "{:.1f}"), ("lost_share", "lost share", "{:.3f}"),
           ("tracked_uncertainty", "υ tracked", "{:.1f}"), ("ate_m", "ATE (m)", "{:.3f}"))


def _runs(path: Path) -> dict[int, dict[str, str]]:
    with path.open(encoding="utf-8") as fh:
        rows = {int(r["seed"]): r for r in csv.DictReader(fh)}
    dropped = [s for s, r in rows.items() if int(r["frames_dropped"] or 0)]
    if dropped:
        raise SystemExit(f"{path}: seeds {dropped} dropped camera frames; rerun with fewer jobs")
    return rows


def main(without: Path, with_restores: Path) -> None:
    off, on = _runs(without), _runs(with_restores)
    seeds = sorted(off)
    if sorted(on) != seeds:
        raise SystemExit("the two folders hold different seeds: no pairing")
    print("| seed | " + " | ".join(f"{label}, none / restores" for _, label, _ in METRICS)
          + " |")
    print("|---|" + "---|" * len(METRICS))
    for s in seeds:
        cells = [f"{fmt.format(float(off[s][k]))} / {fmt.format(float(on[s][k]))}"
                 for k, _, fmt in METRICS]
        print(f"| {s} | " + " | ".join(cells) + " |")
    cells = []
    for k, _, fmt in METRICS:
        d = paired_difference(np.array([[float(on[s][k]) for s in seeds]]),
                              [float(off[s][k]) for s in seeds])
        cells.append(f"{fmt.format(d.mean)} [{fmt.format(d.low)}, {fmt.format(d.high)}]")
    print("| paired, restores − none | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    if len(sys.argv) != 3:
        raise SystemExit(__doc__)
    main(Path(sys.argv[1]), Path(sys.argv[2]))
