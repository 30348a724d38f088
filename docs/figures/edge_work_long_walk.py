"""The long walk's table: what one device costs the edge over a walk, from the per-slot CSVs
``python -m bench.edge_work … --csv`` writes, rounds side by side.

    python docs/figures/edge_work_long_walk.py BEFORE.csv[,BEFORE2.csv] AFTER.csv[,AFTER2.csv]

Each row of a CSV is one device-slot, each column but ``slot`` one of its steps (ms); a
device-slot is their sum.
"""

from __future__ import annotations

import argparse
import csv
import statistics
from pathlib import Path


def _slots(path: Path) -> list[dict[str, float]]:
    with path.open() as fh:
        return [{k: float(v) for k, v in row.items() if k != "slot"}
                for row in csv.DictReader(fh)]


def summary(path: Path) -> dict[str, str]:
    """One run's figures, each as the table prints it."""
    rows = _slots(path)
    per_slot = [sum(row.values()) for row in rows]
    first, last = per_slot[:30], per_slot[-30:]
    loop = [row["loop closer"] for row in rows]
    checkpoint = [row["checkpoint"] for row in rows]
    archive = [row["archive"] for row in rows]
    return {
        "the edge's walk, every step": f"{sum(per_slot):,.0f} ms".replace(",", " "),
        "median device-slot": f"{statistics.median(per_slot):.1f} ms",
        "median device-slot, slots 1–30 / the last 30":
            f"{statistics.median(first):.1f} / {statistics.median(last):.1f} ms",
        "the loop closer over the walk (median a slot)":
            f"{sum(loop):,.0f} ms ({statistics.median(loop):.1f})".replace(",", " "),
        "its last 30 slots' median": f"{statistics.median(loop[-30:]):.1f} ms",
        "the checkpoint over the walk (median a slot)":
            f"{sum(checkpoint):,.0f} ms ({statistics.median(checkpoint):.1f})"
            .replace(",", " "),
        "the archive step over the walk (median a slot, p95)":
            f"{sum(archive):,.0f} ms".replace(",", " ")
            + f" ({statistics.median(archive):.1f}, "
              f"{statistics.quantiles(archive, n=20)[-1]:.1f})",
        "slots": str(len(rows)),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("before", help="the CSVs of the runs before, comma-separated")
    parser.add_argument("after", help="the CSVs of the runs after, comma-separated")
    args = parser.parse_args()
    before = [summary(Path(p)) for p in args.before.split(",")]
    after = [summary(Path(p)) for p in args.after.split(",")]
    print("| | before (rounds " + ", ".join(str(i + 1) for i in range(len(before)))
          + ") | after (rounds " + ", ".join(str(i + 1) for i in range(len(after))) + ") |")
    print("|---|---|---|")
    for key in before[0]:
        print(f"| {key} | {', '.join(run[key] for run in before)} | "
              f"{', '.join(run[key] for run in after)} |")


if __name__ == "__main__":
    main()
