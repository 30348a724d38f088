"""The edge's map in pieces with ``connected_map`` off and on (docs/results/map-consistency.md,
"A map that stays one graph"): ``bench.map_pieces`` runs, the two arms of each seed paired.
Prints a markdown table a CSV: each figure seed by seed in both arms, and the paired
difference (on − off, Student's t, :func:`twinslam.reporting.paired_row`); with ``--figure``
draws the slots in pieces and the edge's lost share seed by seed, off and on, a row a CSV.

    .venv/bin/python docs/figures/map_pieces_table.py CSV [CSV ...] [--figure PNG]
"""

from __future__ import annotations

import argparse
import csv
from pathlib import Path

import numpy as np

from twinslam.reporting import paired_row, pyplot

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


def figure(paths: list[Path], out: Path) -> None:
    """Two panels a CSV: the slots in pieces and the edge's lost share, seed by seed."""
    plt = pyplot()
    fig, axes = plt.subplots(len(paths), 2, figsize=(11, 3.2 * len(paths)), squeeze=False)
    for row, path in zip(axes, paths, strict=True):
        off, on = arms(path)
        seeds = sorted(off.keys() & on.keys())
        x = np.arange(len(seeds))
        for ax, (column, label, scale) in zip(row, (
                ("pieces_slots", "slots with the map in pieces", 1.0),
                ("edge_lost_share", "the edge's lost share, %", 100.0)), strict=True):
            for shift, (arm, name) in zip((-0.2, 0.2), ((off, "connected_map off"),
                                                       (on, "on (the default)")), strict=True):
                ax.bar(x + shift, [float(arm[s][column]) * scale for s in seeds], 0.4,
                       label=name)
            ax.set_xticks(x, [str(s) for s in seeds])
            ax.set_xlabel("seed")
            ax.set_ylabel(label)
            ax.legend(fontsize=8)
        first = off[seeds[0]]
        row[0].set_title(f"{Path(first['sequence']).name}, {first['order']}, "
                         f"{first['uplink']}" + (f", {first['device_params']}"
                                                 if first.get("device_params") else ""),
                         fontsize=9, loc="left")
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    print(f"wrote {out}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("csv", type=Path, nargs="+", help="bench.map_pieces CSVs")
    parser.add_argument("--figure", type=Path, metavar="PNG",
                        help="also draw the slots in pieces and the lost share, seed by seed")
    args = parser.parse_args()
    print("\n\n".join("\n".join(table(path)) for path in args.csv))
    if args.figure:
        figure(args.csv, args.figure)


if __name__ == "__main__":
    main()
