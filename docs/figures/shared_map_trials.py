"""One change to the shared map, before against after, over trials that differ by where the
devices start (docs/results/shared-map.md, "On the same frames"): ``bench.shared_map`` runs
paired by (seed, first device's start, second device's start), so that runs of one seed
whose first device starts elsewhere count as trials of their own — on the 7-Scenes walk a
seed varies only the uplinks, and several seeds can make one merge. Prints the paired
difference (after − before, Student's t, :func:`twinslam.reporting.paired_row`) of
the figures :mod:`shared_map_before_after` compares.

Reads ``uplink-two-ends-covered.csv`` from each folder.

    .venv/bin/python docs/figures/shared_map_trials.py BEFORE AFTER
"""

from __future__ import annotations

import argparse
import csv
from pathlib import Path

from shared_map_before_after import METRICS

from twinslam.reporting import paired_row

#: the columns that tell one trial from another
TRIAL = ("seed", "first_start", "second_start")


def trials(folder: Path) -> dict[tuple[int, ...], dict[str, str]]:
    """(seed, first start, second start) → the run's CSV row."""
    with (folder / "uplink-two-ends-covered.csv").open(encoding="utf-8") as fh:
        return {tuple(int(r[c]) for c in TRIAL): r for r in csv.DictReader(fh)}


def table(before: Path, after: Path) -> list[str]:
    """The paired differences, a row a metric both folders' runs have, and the trials."""
    old, new = trials(before), trials(after)
    keys = sorted(old.keys() & new.keys())
    if not keys:
        raise SystemExit(f"{before} and {after} have no trial in common")
    lines = ["| metric | before (trial by trial) | after | after − before |",
             "|---|---|---|---|"]
    for column, name, scale in METRICS:
        if not all(r[k].get(column) for r in (old, new) for k in keys):
            continue
        lines.append(paired_row(name, [float(old[k][column]) * scale for k in keys],
                                [float(new[k][column]) * scale for k in keys]))
    lines.append("| merge slot | " + ", ".join(old[k]["merge_slot"] for k in keys) + " | "
                 + ", ".join(new[k]["merge_slot"] for k in keys) + " | |")
    lines.append("| trials (seed/first start/second start) | "
                 + ", ".join("/".join(map(str, k)) for k in keys) + " | | |")
    return lines


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("before", type=Path, help="the folder of the runs before the change")
    parser.add_argument("after", type=Path, help="the folder of the runs after it")
    args = parser.parse_args()
    print("\n".join(table(args.before, args.after)))


if __name__ == "__main__":
    main()
