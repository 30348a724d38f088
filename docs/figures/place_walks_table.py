"""Many devices walking one place, two settings compared (docs/results/shared-map.md, "Four
devices along the corridor"): ``bench.place_walks`` runs, one CSV an
arm, the two arms' runs paired by seed. Prints a markdown table: each figure seed by seed in
both arms and the paired difference (second − first, Student's t,
:func:`twinslam.reporting.paired_row`); a figure one arm has not (the slots after a merge,
alone) or one arm's runs predate is left out.

    .venv/bin/python docs/figures/place_walks_table.py FIRST.csv SECOND.csv [--last-device]
        [--names "FIRST NAME,SECOND NAME"]
"""

from __future__ import annotations

import argparse
import csv
import math
from collections.abc import Collection
from pathlib import Path

from twinslam.reporting import paired_row
from twinslam.slam.back_end.map_merging import LENT_VIEW_DEG

#: (column, name in the table, scale, format)
FIGURES = [
    ("copies_mean", "other devices' keyframes a map held, mean over its slots", 1.0,
     "{:.1f}"),
    ("copies_end", "held at the end, every map", 1.0, "{:.0f}"),
    ("adopted", "copies adopted (re-lent ones again)", 1.0, "{:.0f}"),
    ("edge_ms_median", "the edge's median ms a device-slot", 1.0, "{:.1f}"),
    ("edge_ms_merged_median", "the same, the slots after each device's merge", 1.0,
     "{:.1f}"),
    ("edge_ms_mean", "the edge's mean ms a device-slot", 1.0, "{:.1f}"),
    ("uploads", "keyframes uploaded, every device", 1.0, "{:.0f}"),
    ("later_uploads", "keyframes uploaded by the devices after the first", 1.0, "{:.0f}"),
    ("lost_share", "the edge's lost share (%)", 100.0, "{:.2f}"),
    ("map_lost_share", "frames the device's map did not serve, mean over the devices (%)",
     100.0, "{:.2f}"),
    ("tracked_share", "frames tracked (%)", 100.0, "{:.2f}"),
    ("pieces_slots", "device-slots planned on a map in pieces (every frame counted lost)", 1.0,
     "{:.0f}"),
    ("cross_rms_m", "cross-device revisit error RMS (cm)", 100.0, "{:.2f}"),
    ("ate_m_mean", "ATE in the place's frame, mean over the devices (cm)", 100.0, "{:.2f}"),
    ("loops", "loops closed", 1.0, "{:.0f}"),
]


def runs(path: Path) -> dict[int, dict[str, str]]:
    """seed → the run's row (a later run of a seed replaces an earlier one), with the
    uploads of the devices after the first (those that come to ground others mapped) and the
    last device's median edge time a slot (the one whose map has the most to adopt)."""
    with path.open(encoding="utf-8") as fh:
        rows = {int(row["seed"]): row for row in csv.DictReader(fh)}
    for row in rows.values():
        row["later_uploads"] = str(sum(int(n) for n in row["device_uploads"].split(";")[1:]))
        if row.get("device_edge_ms"):
            row["last_edge_ms"] = row["device_edge_ms"].split(";")[-1]
        if not row.get("lent_view_m"):
            # runs from before the bounds of their own: lend_views_once declined within the
            # covered view's, and before it every keyframe was lent
            once = row.get("lend_views_once") == "1"
            row["lent_view_m"] = row["covered_m"] if once else "0"
            row["lent_view_deg"] = row["covered_deg"] if once else str(LENT_VIEW_DEG)
        # a copy's points held already was tried at 39ae973 only: every other run lent them
        row.setdefault("lent_redundant_share", "0")
        # runs from before the walks without a shared image replayed one walk, every frame
        row.setdefault("own_walks", "0")
        row.setdefault("interleave", "1")
    return rows


#: with ``--last-device``, after the edge's mean: the device whose map has the most to adopt
LAST_DEVICE = ("last_edge_ms", "the last device's median ms a slot", 1.0, "{:.1f}")

#: the settings an arm may differ in, named as the edge's parameters
SETTINGS = ("covered_m", "covered_deg", "lent_unseen_slots", "lend_in_view", "merge_min_inliers",
            "lent_view_m", "lent_view_deg", "lent_redundant_share", "own_walks", "interleave")
#: how the table names the settings of the devices' walks
WALKS = {("own_walks", "0"): "one walk", ("own_walks", "1"): "walks of their own"}


def arm(row: dict[str, str], settings: list[str]) -> str:
    """An arm's name in the table: alone, or the ``settings`` it differs in ("merged" where
    it differs only in merging)."""
    named = {name: WALKS.get((name, row[name]), f"{name} {float(row[name]):g}")
             for name in settings}
    if row.get("no_merge") == "1":          # alone, only how the devices walked tells arms apart
        return ", ".join(["alone (no merge)", *(named[name] for name in ("own_walks", "interleave")
                                                  if name in named)])
    return ", ".join(named.values()) or "merged"


def table(first_path: Path, second_path: Path, last_device: bool = False,
          names: tuple[str, str] | None = None,
          only_seeds: Collection[int] | None = None) -> list[str]:
    """The table of two arms: a row a figure (with ``last_device``, the last device's edge
    time too); ``names`` the arms' names where they differ in the code that ran them, not in
    a setting the CSV records; ``only_seeds``: the seeds paired, of those both arms ran (the
    held-out walks, where a setting was tuned on others); None: every seed both ran."""
    first, second = runs(first_path), runs(second_path)
    seeds = sorted(first.keys() & second.keys())
    if only_seeds is not None:
        absent = sorted(set(only_seeds) - set(seeds))
        if absent:
            raise SystemExit(f"seeds {absent} are not in both {first_path} and {second_path}")
        seeds = sorted(set(only_seeds))
    if not seeds:
        raise SystemExit(f"{first_path} and {second_path} share no seed")
    one, two = first[seeds[0]], second[seeds[0]]
    differ = [name for name in SETTINGS if one.get(name) != two.get(name)]
    names = list(names) if names else [arm(one, differ), arm(two, differ)]
    lines = [f"{one['sequence']}, {one['devices']} devices each {one['after']} frames after "
             f"the one before, {one['order']}, uplink {one['uplink']}, seeds "
             f"{', '.join(map(str, seeds))}:", "",
             f"| figure | {names[0]} (seed by seed) | {names[1]} | difference |",
             "|---|---|---|---|"]
    figures = list(FIGURES)
    if last_device:
        figures.insert(next(i for i, f in enumerate(figures) if f[0] == "edge_ms_mean") + 1,
                       LAST_DEVICE)
    for column, name, scale, fmt in figures:
        if any(not runs_[s].get(column) for runs_ in (first, second) for s in seeds):
            continue              # a column some runs predate
        before = [float(first[s][column]) * scale for s in seeds]
        after = [float(second[s][column]) * scale for s in seeds]
        if any(math.isnan(x) for x in before + after):
            continue              # a figure one arm has not (alone, no slot after a merge)
        lines.append(paired_row(name, before, after, fmt))
    return lines


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("first", type=Path, help="the first arm's CSV (bench.place_walks --csv)")
    parser.add_argument("second", type=Path, help="the second arm's CSV")
    parser.add_argument("--last-device", action="store_true",
                        help="also the last device's median edge time a slot (the one whose "
                             "map has the most to adopt)")
    parser.add_argument("--names", metavar="FIRST,SECOND",
                        help="the two arms' names in the table, where they differ in the code "
                             "that ran them rather than in a setting the CSVs record")
    parser.add_argument("--seeds", metavar="S,S,…",
                        help="pair only these seeds (both arms must have run each), e.g. "
                             "the held-out walks; default: every seed both arms ran")
    args = parser.parse_args()
    only_seeds = None
    if args.seeds:
        try:
            only_seeds = [int(s) for s in args.seeds.split(",")]
        except ValueError:
            parser.error(f"--seeds takes whole numbers separated by commas, got {args.seeds!r}")
    names = None
    if args.names:
        given = [n.strip() for n in args.names.split(",")]
        if len(given) != 2 or not all(given):
            parser.error(f"--names takes two names separated by a comma, got {args.names!r}")
        names = (given[0], given[1])
    print("\n".join(table(args.first, args.second, args.last_device, names,
                           only_seeds)))


if __name__ == "__main__":
    main()
