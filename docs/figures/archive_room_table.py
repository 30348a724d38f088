"""The archive's room for a device's own keyframes and its lent copies, two rules side by side
(docs/results/shared-map.md, "The archive's room: the device's own walk or the lent place"):
``bench.shared_map --second forward --second-after 500 --share --share-both --vmax 12
--archive 12`` over seeds 0-4, with the archive ranking own keyframes and lent copies together
(least recently useful first, the rule kept) and with the copies giving way while they fill
half of it (tried, not kept). Prints each figure seed by seed and the paired difference
(Student's t over the seeds whose runs differ: seeds 2 and 3 play the same uplink).

    .venv/bin/python docs/figures/archive_room_table.py
"""

from __future__ import annotations

import csv
from pathlib import Path

from twinslam.reporting import paired_row

HERE = Path(__file__).resolve().parent / "shared-map" / "archive-room"
TOGETHER = HERE / "own-and-lent-ranked-together.csv"
COPIES_FIRST = HERE / "lent-give-way-past-half.csv"
#: the archive's capacity the comparison ran at (the CSVs also hold single runs at others)
ARCHIVE = "12"
#: the seeds compared: seed 3's uplink plays as seed 2's
SEEDS = ("0", "1", "2", "4")
#: (column, what it is, its scale from the CSV's unit)
METRICS = (("first_archive_own", "first map's own keyframes in its archive at the end", 1.0),
           ("first_loops", "loops the first edge closed", 1.0),
           ("second_loops", "loops the second edge closed", 1.0),
           ("second_uploads", "second device's keyframes uploaded", 1.0),
           ("second_lost_share", "second device's lost share (the edge's rule), %", 100.0),
           ("cross_rms_m", "cross-device revisit error RMS, cm", 100.0),
           ("first_ate_m", "first device's ATE, cm", 100.0),
           ("second_ate_m", "second device's ATE, cm", 100.0),
           ("keyframes_cross_rms_m", "the two maps' final keyframes apart, RMS cm", 100.0))


def by_seed(path: Path) -> dict[str, dict[str, str]]:
    """The runs at the compared capacity, by seed (a seed's last run where it ran twice)."""
    with path.open(newline="", encoding="utf-8") as fh:
        return {row["seed"]: row for row in csv.DictReader(fh) if row["archive"] == ARCHIVE}


def main() -> None:
    together, copies_first = by_seed(TOGETHER), by_seed(COPIES_FIRST)
    print(f"seeds {', '.join(SEEDS)}; archive of {ARCHIVE}, V_max 12\n")
    print("| figure | ranked together | copies give way past half | difference |")
    print("|---|---|---|---|")
    for column, name, scale in METRICS:
        old = [float(together[s][column]) * scale for s in SEEDS]
        new = [float(copies_first[s][column]) * scale for s in SEEDS]
        print(paired_row(name, old, new))


if __name__ == "__main__":
    main()
