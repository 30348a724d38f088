"""The comparisons of the rules' map order (docs/results/restores.md, "Restores stay in the
map"), LFF reading ids against LFF reading the entry order, seed by seed; one table row a
metric, mean ± 95 % CI of each and the paired difference (entry − id).

    F=docs/figures/restore-order
    .venv/bin/python docs/figures/restore_order.py live $F/live-revisit-v15.csv
    .venv/bin/python docs/figures/restore_order.py shared-map $F/shared-map-by-id.csv \
        $F/shared-map-by-entry.csv

``live``: the default device on the revisit-v15 walk (one CSV, its ``order`` column);
``shared-map``: ``bench.shared_map``'s mapped place (the device coming to a place another
mapped), one CSV a commit.
"""

from __future__ import annotations

import csv
import sys
from pathlib import Path

from twinslam.reporting import mean_ci95, paired_difference

#: (column, scale, the table's label) of the live runs
METRICS = [("failed_share", 100, "frames failed %"), ("frames_dropped", 1, "frames dropped"),
           ("lost_share", 100, "lost % (the rule's)"), ("mean_uncertainty", 1, "mean υ"),
           ("ate_m", 100, "ATE cm"), ("revisit_error_m", 100, "revisit error cm"),
           ("anchored_revisit_error_m", 100, "anchored revisit error cm"),
           ("duplicate_share", 100, "points there twice %"), ("restores", 1, "restores a run"),
           ("downlink_mb", 1, "downlink MB")]


#: the same of bench.shared_map's runs (the second device comes to the first one's place)
SHARED_MAP = [("second_uploads", 1, "the second device's uploads"),
              ("foreign_at_end", 1, "copies in its edge map at the end"),
              ("second_lost_share", 100, "its edge's lost share %"),
              ("second_map_lost_share", 100, "its frames the map did not serve %"),
              ("second_ate_m", 100, "its ATE cm"), ("first_ate_m", 100, "the first's ATE cm"),
              ("cross_rms_m", 100, "cross-device revisit error cm")]


def _read(path: Path) -> list[dict[str, str]]:
    with path.open(encoding="utf-8") as fh:
        return list(csv.DictReader(fh))


def _by_seed(rows: list[dict[str, str]]) -> list[dict[str, str]]:
    return sorted(rows, key=lambda r: int(r["seed"]))


def table(by_id: list[dict[str, str]], by_entry: list[dict[str, str]],
          metrics: list[tuple[str, float, str]]) -> None:
    """Print the paired table of ``metrics`` over the same seeds of the two orders."""
    if [r["seed"] for r in by_id] != [r["seed"] for r in by_entry]:
        raise SystemExit("the two orders ran different seeds")
    print("| metric | by id | by entry | entry − id (paired) |")
    print("|---|---|---|---|")
    for column, scale, label in metrics:
        ids = [float(r[column]) * scale for r in by_id]
        entry = [float(r[column]) * scale for r in by_entry]
        (a, ha), (b, hb) = mean_ci95(ids), mean_ci95(entry)
        d = paired_difference([entry], ids)
        print(f"| {label} | {a:.2f} ± {ha:.2f} | {b:.2f} ± {hb:.2f} | "
              f"{d.mean:+.2f} [{d.low:+.2f}, {d.high:+.2f}] |")


def main(argv: list[str]) -> None:
    if argv[:1] == ["live"] and len(argv) == 2:
        rows = _read(Path(argv[1]))
        table(_by_seed([r for r in rows if r["order"] == "id"]),
              _by_seed([r for r in rows if r["order"] == "entry"]), METRICS)
    elif argv[:1] == ["shared-map"] and len(argv) == 3:
        table(_by_seed(_read(Path(argv[1]))), _by_seed(_read(Path(argv[2]))), SHARED_MAP)
    else:
        raise SystemExit(__doc__)


if __name__ == "__main__":
    main(sys.argv[1:])
