"""The live comparison of the rules' map order (docs/results/restores.md, "Restores stay in
the map"): the default device on the revisit-v15 walk, seed by seed, LFF reading ids against
LFF reading the entry order; one table row a metric, mean ± 95 % CI of each and the paired
difference (entry − id).

    .venv/bin/python docs/figures/restore_order.py docs/figures/restore-order/live-revisit-v15.csv
"""

from __future__ import annotations

import csv
import sys
from pathlib import Path

from twinslam.reporting import mean_ci95, paired_difference

#: (column, scale, the table's label)
METRICS = [("failed_share", 100, "frames failed %"), ("frames_dropped", 1, "frames dropped"),
           ("lost_share", 100, "lost % (the rule's)"), ("mean_uncertainty", 1, "mean υ"),
           ("ate_m", 100, "ATE cm"), ("revisit_error_m", 100, "revisit error cm"),
           ("anchored_revisit_error_m", 100, "anchored revisit error cm"),
           ("duplicate_share", 100, "points there twice %"), ("restores", 1, "restores a run"),
           ("downlink_mb", 1, "downlink MB")]


def main(path: Path) -> None:
    with path.open(encoding="utf-8") as fh:
        rows = list(csv.DictReader(fh))
    by = {order: sorted((r for r in rows if r["order"] == order), key=lambda r: int(r["seed"]))
          for order in ("id", "entry")}
    if [r["seed"] for r in by["id"]] != [r["seed"] for r in by["entry"]]:
        raise SystemExit(f"{path}: the two orders ran different seeds")
    print("| metric | by id | by entry | entry − id (paired) |")
    print("|---|---|---|---|")
    for column, scale, label in METRICS:
        ids = [float(r[column]) * scale for r in by["id"]]
        entry = [float(r[column]) * scale for r in by["entry"]]
        (a, ha), (b, hb) = mean_ci95(ids), mean_ci95(entry)
        d = paired_difference([entry], ids)
        print(f"| {label} | {a:.2f} ± {ha:.2f} | {b:.2f} ± {hb:.2f} | "
              f"{d.mean:+.2f} [{d.low:+.2f}, {d.high:+.2f}] |")


if __name__ == "__main__":
    main(Path(sys.argv[1]))
