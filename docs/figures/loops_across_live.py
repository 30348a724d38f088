"""Loops across devices, live (docs/results/shared-map.md, "Loops across devices"): two
fleets' runs side by side, seed by seed — by default the edge's default and
``loops_across_devices: false`` — the paired difference of what a user of the shared map sees
(the cross-device revisit error, each device's ATE, uploads), what the edge spent, and what
says whether the run can be trusted (camera frames dropped, frames untracked, late maps), and
a figure of the cross-device error seed by seed.

Reads ``{AFTER}-seed{S}.csv`` and ``{BEFORE}-seed{S}.csv`` from the folder (by default
``across`` and ``own``): each run's ``fleet_runs.csv`` (``twinslam launch --devices 2 …
--out OUT``, the page has the command); writes ``cross-device.png`` there (``--figure``
names another), with a second panel over the last third of each device's frames where the
runs have it.

    .venv/bin/python docs/figures/loops_across_live.py docs/figures/shared-map/loops-across/live
    .venv/bin/python docs/figures/loops_across_live.py FOLDER \
        --before "one:one cooldown for both kinds" --after "per-kind:a cooldown per kind"
"""

from __future__ import annotations

import argparse
import csv
import re
from pathlib import Path

from twinslam.reporting import paired_row, pyplot

#: (column, what it is, scale from the CSV's unit, summed over the devices or per device)
METRICS = (("cross_device_rms_m", "cross-device revisit error RMS, cm", 100.0, "pair"),
           # on the same frames whenever the merges came (runs since 2026-12-02, midday)
           ("cross_device_late_rms_m", "cross-device error over the last third of each "
            "device's frames, cm", 100.0, "pair"),
           ("ate_m", "ATE, cm", 100.0, "device"),
           ("frames_uploaded", "frames uploaded", 1.0, "device"),
           ("edge_ms_median", "the edge's median ms a slot", 1.0, "device"),
           ("frames_dropped", "camera frames dropped (both devices)", 1.0, "sum"),
           ("untracked_frames", "frames untracked (both devices)", 1.0, "sum"),
           ("late_slots", "maps late (both devices)", 1.0, "sum"))
#: what the edge's map did, with ``--map`` (a comparison of the map's management)
MAP_METRICS = (("map_in_pieces_slots", "slots with the edge's map in pieces", 1.0, "device"),
               ("lost_share", "the edge's lost share, %", 100.0, "device"))
#: the two modes compared by default: file prefix and its column's label
BEFORE = ("own", "own loops only")
AFTER = ("across", "with loops across devices")


def runs(folder: Path, mode: str) -> dict[int, list[dict[str, str]]]:
    """seed → the run's rows (one a device) for ``mode``."""
    found = {}
    for path in sorted(folder.glob(f"{mode}-seed*.csv")):
        match = re.fullmatch(rf"{mode}-seed(\d+)\.csv", path.name)
        if match:
            with path.open(encoding="utf-8") as fh:
                found[int(match.group(1))] = list(csv.DictReader(fh))
    return found


def values(rows: list[dict[str, str]], column: str, scale: float, kind: str
           ) -> dict[str, float]:
    """A run's figure: ``pair`` the first device's row (the pair's error, the same on both),
    ``sum`` over the devices, ``device`` each device's."""
    if kind == "pair":
        return {"pair": float(rows[0][column]) * scale}
    if kind == "sum":
        return {"both": sum(float(r[column]) for r in rows) * scale}
    return {r["device"]: float(r[column]) * scale for r in rows}


def table(folder: Path, modes: tuple[tuple[str, str], tuple[str, str]] = (BEFORE, AFTER),
          with_map: bool = False) -> tuple[list[str], list[int], dict[str, list[float]]]:
    """The markdown table of ``modes`` ((prefix, label) before, after), the seeds both ran,
    and the cross-device error per mode's prefix (``with_map``: :data:`MAP_METRICS` too)."""
    (old, old_label), (new, new_label) = modes
    first, then = runs(folder, old), runs(folder, new)
    seeds = sorted(first.keys() & then.keys())
    if not seeds:
        raise SystemExit(f"{folder}: no seed has both {old}-seedS.csv and {new}-seedS.csv")
    lines = [f"| figure | {old_label} (seed by seed) | {new_label} | {new} − {old} |",
             "|---|---|---|---|"]
    cross: dict[str, list[float]] = {}
    for column, name, scale, kind in METRICS + (MAP_METRICS if with_map else ()):
        if not all(r[s][0].get(column) for r in (first, then) for s in seeds):
            continue                  # a column older runs lack
        if all(r[s][0][column] == "nan" for r in (first, then) for s in seeds):
            continue                  # no run has the figure (no pair over the last thirds)
        per = {m: [values(r[s], column, scale, kind) for s in seeds]
               for m, r in ((old, first), (new, then))}
        for who in per[old][0]:
            before = [v[who] for v in per[old]]
            after = [v[who] for v in per[new]]
            label = name if who in ("pair", "both") else f"{who} {name}"
            lines.append(paired_row(label, before, after,
                                    "{:.1f}" if scale != 1.0 else "{:.0f}"))
            if column == "cross_device_rms_m":
                cross = {old: before, new: after}
    lines.append(f"| seeds | {', '.join(str(s) for s in seeds)} | | |")
    return lines, seeds, cross


def mode(arg: str) -> tuple[str, str]:
    """``PREFIX:LABEL`` as (prefix, label)."""
    prefix, sep, label = arg.partition(":")
    if not sep or not prefix or not label:
        raise argparse.ArgumentTypeError(f"{arg!r}: expected PREFIX:LABEL")
    return prefix, label


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("folder", type=Path, help="the folder of BEFORE-seedS.csv and "
                                                   "AFTER-seedS.csv runs")
    parser.add_argument("--before", type=mode, default=BEFORE, metavar="PREFIX:LABEL",
                        help="the runs compared against: their files' prefix and the column's "
                             f"label (default {':'.join(BEFORE)})")
    parser.add_argument("--after", type=mode, default=AFTER, metavar="PREFIX:LABEL",
                        help=f"the runs compared (default {':'.join(AFTER)})")
    parser.add_argument("--map", action="store_true",
                        help="also the slots each device's edge map was in pieces and the "
                             "edge's lost share")
    parser.add_argument("--figure", default="cross-device.png", metavar="NAME",
                        help="the figure's file name in the folder (two comparisons in one "
                             "folder: one name each); default %(default)s")
    parser.add_argument("--title", default="two devices from the walk's two ends, live",
                        help="the figure's title: the scenario the runs played; default "
                             "%(default)s")
    args = parser.parse_args(argv)
    modes = (args.before, args.after)
    lines, seeds, cross = table(args.folder, modes, args.map)
    print("\n".join(lines))
    late = late_errors(args.folder, modes, seeds)
    panels = [("cross-device revisit error RMS, cm", cross)]
    if late:
        panels.append(("the same over the last third of\neach device's frames, cm", late))
    plt = pyplot()
    fig, axes = plt.subplots(1, len(panels), figsize=(6 * len(panels), 3.5), squeeze=False)
    for ax, (ylabel, values_by_mode) in zip(axes[0], panels, strict=True):
        for (prefix, label), marker in zip(modes, ("o", "s"), strict=True):
            ax.plot(seeds, values_by_mode[prefix], marker=marker, linestyle="-", label=label)
        ax.set_xlabel("seed (the uplinks' draws)")
        ax.set_ylabel(ylabel)
        ax.set_xticks(seeds)
        ax.legend(fontsize=8)
    fig.suptitle(args.title, fontsize=10)
    fig.tight_layout()
    out = args.folder / args.figure
    fig.savefig(out, dpi=120)
    print(f"wrote {out}")


def late_errors(folder: Path, modes: tuple[tuple[str, str], tuple[str, str]],
                seeds: list[int]) -> dict[str, list[float]]:
    """Each mode's cross-device error over the last third of each device's frames, seed by
    seed, in cm; empty where a run lacks the column (runs before 2026-12-02, midday)."""
    found = {}
    for prefix, _ in modes:
        by_seed = runs(folder, prefix)
        cells = [by_seed[s][0].get("cross_device_late_rms_m") for s in seeds]
        if not all(cells) or all(c == "nan" for c in cells):
            return {}
        found[prefix] = [float(c) * 100.0 for c in cells if c]
    return found


if __name__ == "__main__":
    main()
