"""The edge's map in pieces with ``connected_map`` off and on (docs/results/map-consistency.md,
"A map that stays one graph"): ``bench.map_pieces`` runs, the two arms of each seed paired.
Prints a markdown table a CSV: each figure seed by seed in both arms, and the paired
difference (on − off, Student's t, :func:`twinslam.reporting.paired_row`).

    .venv/bin/python docs/figures/map_pieces_table.py CSV [CSV ...]
"""

from __future__ import annotations

import argparse
import csv
from pathlib import Path

from twinslam.reporting import paired_row

#: (column, name in the table, scale, format)
FIGURES = [
    ("pieces_slots", "slots with the map in pieces", 1.0, "{:.0f}"),
    ("edge_lost_share", "the edge's lost share (%)", 100.0, "{:.1f}"),
    ("device_lost_share", "the device's own lost share (%)", 100.0, "{:.1f}"),
    ("frames_tracked", "frames tracked", 1.0, "{:.0f}"),
    ("uploads", "uploads", 1.0, "{:.0f}"),
    ("ate_m", "ATE (cm)", 100.0, "{:.2f}"),
    ("mended_slots", "slots mended", 1.0, "{:.0f}"),
]


def arms(path: Path) -> tuple[dict[int, dict[str, str]], dict[int, dict[str, str]]]:
    """(off, on): seed → the run's row."""
    off: dict[int, dict[str, str]] = {}
    on: dict[int, dict[str, str]] = {}
    with path.open(encoding="utf-8") as fh:
        for row in csv.DictReader(fh):
            (on if row["connected_map"] == "1" else off)[int(row["seed"])] = row
    return off, on


def table(path: Path) -> list[str]:
    """The table of one CSV: a row a figure."""
    off, on = arms(path)
    seeds = sorted(off.keys() & on.keys())
    if not seeds:
        raise SystemExit(f"{path} has no seed run in both arms")
    first = off[seeds[0]]
    device = f", the device's {first['device_params']}" if first.get("device_params") else ""
    lines = [f"{first['sequence']}, {first['order']}, uplink {first['uplink']}{device}, seeds "
             f"{', '.join(map(str, seeds))}:", "",
             "| figure | off (seed by seed) | on | on − off |", "|---|---|---|---|"]
    for column, name, scale, fmt in FIGURES:
        lines.append(paired_row(name, [float(off[s][column]) * scale for s in seeds],
                                [float(on[s][column]) * scale for s in seeds], fmt))
    return lines


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("csv", type=Path, nargs="+", help="bench.map_pieces CSVs")
    args = parser.parse_args()
    print("\n\n".join("\n".join(table(path)) for path in args.csv))


if __name__ == "__main__":
    main()
