"""One change to the shared map, before against after (docs/results/shared-map.md, "One loop
closing for the place"): for each scenario and condition of ``bench.shared_map`` runs in two
folders, the paired difference (after − before, Student's t over the seeds both ran,
:func:`twinslam.reporting.paired_row`) of what a user of the shared map sees — the
cross-device revisit error, the two edge maps' final keyframes against each other, the
second device's uploads, its ATE and the share of its frames it held on its own features
instead of the map — and a figure of the cross-device error and that share, seed by seed.

Reads ``uplink-{SCENARIO}-{lent,covered}.csv`` from each folder (the page has the commands;
a scenario and condition one folder lacks is left out; the corridor's two ends as the
scenario ``corridor-two-ends``) and writes ``before-after.png`` into the after folder;
``--adoptions`` adds how many keyframes each map adopted from the other; ``--both-devices``
the first device's ATE and the share of each device's frames the edge counts lost (the
paper's objective: a change to the device's tracking shows there).

    .venv/bin/python docs/figures/shared_map_before_after.py BEFORE AFTER [--adoptions]
                                                             [--both-devices]
"""

from __future__ import annotations

import argparse
from pathlib import Path

from shared_uplink_table import SCENARIOS, distinct_seeds, runs

from twinslam.reporting import paired_row, pyplot, seed_lines

#: the conditions compared: lending with every frame a candidate, and with covered frames out
CONDITIONS = ("lent", "covered")
#: the scenarios compared: the uplink table's and the corridor walked from its two ends
COMPARED_SCENARIOS = (*SCENARIOS, "corridor-two-ends")
#: (column, what it is, its unit's scale from the CSV's)
METRICS = (("cross_rms_m", "cross-device revisit error RMS, cm", 100.0),
           # on the same frames whenever the merge came (runs since 2026-12-02, midday)
           ("cross_last_rms_m", "cross-device error over the second device's last 300 "
            "frames, cm", 100.0),
           ("keyframes_cross_rms_m", "the two maps' final keyframes apart, RMS cm", 100.0),
           ("second_uploads", "second device's keyframes uploaded", 1.0),
           ("second_ate_m", "second device's ATE, cm", 100.0),
           ("second_map_lost_share", "second device's frames off the map, %", 100.0),
           ("first_map_lost_share", "first device's frames off the map, %", 100.0))
#: with --adoptions: what lending cost each map (columns every run with --share has)
ADOPTIONS = (("adopted", "first device's keyframes the second map adopted", 1.0),
             ("adopted_back", "second device's keyframes the first map adopted", 1.0))
#: with --both-devices: the first device's figures beside the second's, and the frames the
#: edge counts lost (a change to the devices' tracking moves both)
BOTH_DEVICES = (("first_ate_m", "first device's ATE, cm", 100.0),
                ("first_lost_share", "first device's frames the edge counts lost, %", 100.0),
                ("second_lost_share", "second device's frames the edge counts lost, %", 100.0))


def paired(before: Path, after: Path, scenario: str, condition: str,
           metrics: tuple[tuple[str, str, float], ...] = METRICS
           ) -> tuple[list[int], dict[str, tuple[list[float], list[float]]]]:
    """The seeds both folders ran — less a seed whose runs repeat an earlier seed's in both
    (two seeds can draw one uplink: a repeated run is no second sample) — and each metric's
    (before, after) values over them."""
    old, new = runs(before, scenario, condition), runs(after, scenario, condition)
    seeds = distinct_seeds({"before": old, "after": new})
    return seeds, {column: ([float(old[s][column]) * scale for s in seeds],
                            [float(new[s][column]) * scale for s in seeds])
                   for column, _, scale in metrics
                   if all(r[s].get(column) for r in (old, new) for s in seeds)}


def compared(before: Path, after: Path) -> list[tuple[str, str]]:
    """The (scenario, condition) pairs both folders have runs of."""
    return [(s, c) for s in COMPARED_SCENARIOS for c in CONDITIONS
            if all((folder / f"uplink-{s}-{c}.csv").exists() for folder in (before, after))]


def table(before: Path, after: Path, adoptions: bool = False, both_devices: bool = False
          ) -> list[str]:
    """The paired differences, a row a scenario, condition and metric (with ``adoptions``,
    the keyframes each map adopted too; with ``both_devices``, the first device's ATE and
    each device's frames the edge counts lost)."""
    metrics = (*METRICS, *(ADOPTIONS if adoptions else ()),
               *(BOTH_DEVICES if both_devices else ()))
    lines = ["| scenario | condition | metric | before (seed by seed) | after | after − before |",
             "|---|---|---|---|---|---|"]
    for scenario, condition in compared(before, after):
        seeds, values = paired(before, after, scenario, condition, metrics)
        for column, name, _ in metrics:
            if column not in values:
                continue                  # a column older runs lack
            old, new = values[column]
            lines.append(paired_row(f"{scenario} | {condition} | {name}", old, new))
        lines.append(f"| {scenario} | {condition} | seeds | {', '.join(map(str, seeds))} | | |")
    return lines


def figure(before: Path, after: Path) -> Path:
    """Cross-device error and the second device's frames off the map, before → after, one
    line a seed, a panel a scenario and condition."""
    plt = pyplot()
    panels = compared(before, after)
    width = max(3.2 * len(panels), 5.6)     # one panel: room for the title
    fig, axes = plt.subplots(2, len(panels), figsize=(width, 6.4), sharey="row", squeeze=False)
    for col, (scenario, condition) in enumerate(panels):
        seeds, values = paired(before, after, scenario, condition)
        for row, column in enumerate(("cross_rms_m", "second_map_lost_share")):
            ax = axes[row][col]
            seed_lines(ax, seeds, *values[column])
            if row == 0:
                ax.set_title(f"{scenario}, {condition}", fontsize=9)
            if col == 0:
                ax.set_ylabel(dict((c, n) for c, n, _ in METRICS)[column], fontsize=8)
    fig.suptitle("Shared map, before and after: one line a seed (blue: lower after)",
                 fontsize=10)
    fig.tight_layout()
    out = after / "before-after.png"
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("before", type=Path, help="the folder of the runs before the change")
    parser.add_argument("after", type=Path, help="the folder of the runs after it (the figure "
                        "is written there)")
    parser.add_argument("--adoptions", action="store_true",
                        help="also compare how many keyframes each map adopted from the other")
    parser.add_argument("--both-devices", action="store_true",
                        help="also compare the first device's ATE and the share of each "
                        "device's frames the edge counts lost")
    args = parser.parse_args()
    print("\n".join(table(args.before, args.after, args.adoptions, args.both_devices)))
    print(f"wrote {figure(args.before, args.after)}")


if __name__ == "__main__":
    main()
