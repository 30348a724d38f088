"""A device's own keyframes of an earlier visit covering its views, against the paper's
uploads (docs/results/shared-map.md, "A device coming back to where it was"): two
``bench.shared_map --no-merge`` CSVs of the same seeds, each run two devices alone on one
edge in two places walked forward and back (the first the 7-Scenes kitchen, the second the
synthetic corridor), one with ``--own-coverage-after 0`` (before) and one with another
value (after); ``--places`` names the two places when they are others. Prints, for each
device, the paired difference (after − before, Student's t
over the seeds both ran, :func:`twinslam.reporting.paired_row`) of its uploads, the frames
the edge counts lost and those its map did not serve, its ATE, its revisit error against
itself, the loops its edge closed, the keyframes its archive held at the end and the edge's
median time a slot; and draws the after CSV's ``.png`` beside it: uploads and lost frames,
one line a seed.

    .venv/bin/python docs/figures/own_coverage_table.py BEFORE.csv AFTER.csv
        [--places FIRST [SECOND]]
"""

from __future__ import annotations

import argparse
import csv
from pathlib import Path

from twinslam.reporting import paired_row, pyplot, seed_lines

#: the two devices of a run, by the CSV's column prefix
DEVICES = ("first", "second")
#: the places they walk by default
PLACES = ("7-Scenes kitchen, forward and back", "synthetic corridor, out and back")
#: (column without its device prefix, what it is, its unit's scale from the CSV's)
METRICS = (("uploads", "keyframes uploaded", 1.0),
           ("lost_share", "frames the edge counts lost, %", 100.0),
           ("map_lost_share", "frames its map did not serve, %", 100.0),
           ("ate_m", "ATE, cm", 100.0),
           ("self_rms_m", "revisit error against itself, cm", 100.0),
           ("loops", "loops closed", 1.0),
           ("archive_own", "keyframes archived at the end", 1.0),
           ("edge_ms", "the edge's median time a slot, ms", 1.0))


def runs(path: Path) -> dict[int, dict[str, str]]:
    """The CSV's runs by seed (a seed run twice: its last run)."""
    with path.open(newline="", encoding="utf-8") as fh:
        return {int(row["seed"]): row for row in csv.DictReader(fh)}


def paired(before: Path, after: Path) -> tuple[list[int], dict[str, tuple[list[float],
                                                                          list[float]]]]:
    """The seeds both files ran and each device's metric's (before, after) values over them,
    keyed ``{device}_{column}``. Refuses two files of one setting, or a run that merged
    (the two devices are in two places: a merge is a false one)."""
    old, new = runs(before), runs(after)
    seeds = sorted(set(old) & set(new))
    if not seeds:
        raise SystemExit(f"{before} and {after} share no seed")
    for name, rows in (("before", old), ("after", new)):
        if any(rows[s].get("merged") == "1" for s in seeds):
            raise SystemExit(f"a run {name} merged its two places: not a run of devices alone")
    if {old[s].get("own_coverage_after") for s in seeds} & \
            {new[s].get("own_coverage_after") for s in seeds}:
        raise SystemExit("before and after ran one own_coverage_after setting")
    values = {}
    for device in DEVICES:
        for column, _, scale in METRICS:
            key = f"{device}_{column}"
            if all(r[s].get(key) for r in (old, new) for s in seeds):
                values[key] = ([float(old[s][key]) * scale for s in seeds],
                               [float(new[s][key]) * scale for s in seeds])
    return seeds, values


def table(before: Path, after: Path, places: tuple[str, ...] = PLACES) -> list[str]:
    """The paired differences, a row a device (named by the place it walked; with one place
    named, the first device's alone) and metric, then the seeds."""
    seeds, values = paired(before, after)
    lines = ["| device | metric | before (seed by seed) | after | after − before |",
             "|---|---|---|---|---|"]
    for device, place in zip(DEVICES, places, strict=False):
        for column, name, _ in METRICS:
            key = f"{device}_{column}"
            if key in values:
                fmt = "{:.0f}" if column in ("uploads", "loops", "archive_own") else "{:.1f}"
                lines.append(paired_row(f"{place} | {name}", *values[key], fmt=fmt))
    lines.append(f"| {'both' if len(places) > 1 else 'it'} | seeds | "
                 f"{', '.join(map(str, seeds))} | | |")
    return lines


def figure(before: Path, after: Path, places: tuple[str, ...] = PLACES) -> Path:
    """Uploads and frames the edge counts lost, before → after, one line a seed, a column a
    device (of those ``places`` names); written beside ``after`` as ``{its stem}.png``."""
    plt = pyplot()
    seeds, values = paired(before, after)
    shown = (("uploads", "keyframes uploaded"), ("lost_share", "frames counted lost, %"))
    fig, axes = plt.subplots(len(shown), len(places), figsize=(3.6 * len(places), 6.0),
                             squeeze=False)
    for col, (device, place) in enumerate(zip(DEVICES, places, strict=False)):
        for row, (column, label) in enumerate(shown):
            ax = axes[row][col]
            seed_lines(ax, seeds, *values[f"{device}_{column}"],
                       ("own keyframes\ncover nothing", "of an earlier\nvisit cover"))
            if row == 0:
                ax.set_title(place, fontsize=9)
            if col == 0:
                ax.set_ylabel(label, fontsize=8)
    fig.suptitle("A device coming back: one line a seed (blue: lower after)", fontsize=10)
    fig.tight_layout()
    out = after.with_suffix(".png")
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("before", type=Path, help="the runs with --own-coverage-after 0")
    parser.add_argument("after", type=Path, help="the runs with another value (the figure "
                        "is written beside it)")
    parser.add_argument("--places", nargs="+", default=PLACES, metavar="PLACE",
                        help="the first and the second device's places; one name: the first "
                        "device's figures alone (where the second device's runs repeat "
                        "another seed's first device's) (default: %(default)s)")
    args = parser.parse_args()
    if len(args.places) > len(DEVICES):
        parser.error(f"--places: one or two names, got {len(args.places)}")
    places = tuple(args.places)
    print("\n".join(table(args.before, args.after, places)))
    print(f"wrote {figure(args.before, args.after, places)}")


if __name__ == "__main__":
    main()
