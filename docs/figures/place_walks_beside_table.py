"""One place walk in two trees (docs/benchmarks/shared-place.md): ``bench.place_walks
--baseline COMMIT --csv FILE`` runs, one CSV a seed, each holding the baseline's row and this
tree's. Prints a markdown table of the edge's ms a device-slot in both trees, paired by seed,
and the devices' own medians paired device by device over every seed (this tree − the
baseline, Student's t, :func:`twinslam.reporting.paired_row`); and says which figures other
than the timings differ between the trees (none, where the change only sped the edge up) —
where some do, the walk's own figures side by side (cross-device error, ATE, loops, uploads,
lost share, copies; each device's ATE device by device).

With ``--looks`` a row more: the median of a merge look's worker time (``look_ms_median``),
outside the device-slots (the looks run beside the slots, as on the node's worker). With
``--merges`` another: the slot of its own walk at which each later device's map merged,
device by device over the devices merged in both trees, and the false merges (a device
joining another place's) of each tree, counted under the table.

    .venv/bin/python docs/figures/place_walks_beside_table.py [--looks] [--merges]
        SEED_0.csv SEED_1.csv …
"""

from __future__ import annotations

import argparse
import csv
from pathlib import Path

from twinslam.reporting import paired_row

#: (column, name in the table): the run's figures of the edge's ms a device-slot
TIMINGS = [
    ("edge_ms_mean", "the edge's mean ms a device-slot, every device"),
    ("edge_ms_median", "its median"),
    ("edge_ms_merged_median", "its median over the slots after each device's merge"),
]
#: (column, name in the table, scale, format): the walk's own figures, shown side by side
#: where the two trees walked different walks (a change that alters what the edge decides)
WALK = [
    ("cross_rms_m", "cross-device revisit error, cm", 100.0, "{:.2f}"),
    ("ate_m_mean", "ATE, cm (the devices' mean)", 100.0, "{:.2f}"),
    ("loops", "loops closed", 1.0, "{:.0f}"),
    ("uploads", "keyframes uploaded", 1.0, "{:.0f}"),
    ("lost_share", "the edge's lost share, %", 100.0, "{:.1f}"),
    ("copies_mean", "copies a map holds (mean over its slots)", 1.0, "{:.1f}"),
]
#: the figures two trees share when they walked one walk (``bench.place_walks.SAME_WALK``;
#: the scripts here run without the bench package on their path)
SAME_WALK = ("merged", "copies_mean", "copies_end", "adopted", "uploads", "lost_share",
             "tracked_share", "ate_m_mean", "cross_rms_m", "loops", "device_uploads",
             "device_merge_slot", "device_ate_m")


def pair(path: Path) -> tuple[dict[str, str], dict[str, str]]:
    """The baseline's row and this tree's of one side-by-side run (the first round's)."""
    with path.open(encoding="utf-8") as fh:
        rows = [row for row in csv.DictReader(fh) if row["round"] == "1"]
    trees = {row["tree"]: row for row in rows}
    if set(trees) != {"baseline", "current"}:
        raise SystemExit(f"{path}: not a bench.place_walks --baseline table")
    return trees["baseline"], trees["current"]


def table(paths: list[Path], looks: bool = False, merges: bool = False) -> list[str]:
    """The table, a row a timing and one for the devices' medians (and with ``looks`` one
    for the merge looks' median, with ``merges`` one for the merges' slots and a line for
    the false merges), then what differed."""
    pairs = [pair(p) for p in paths]
    seeds = [int(base["seed"]) for base, _ in pairs]
    first = pairs[0][0]
    lines = [f"{first['sequence']}, {first['devices']} devices each {first['after']} frames "
             f"after the one before, uplink {first['uplink']}, seeds "
             f"{', '.join(map(str, seeds))}:", "",
             "| figure | the baseline (seed by seed) | this tree | difference |",
             "|---|---|---|---|"]
    for column, name in TIMINGS:
        lines.append(paired_row(name, [float(b[column]) for b, _ in pairs],
                                [float(c[column]) for _, c in pairs]))
    before = [float(ms) for b, _ in pairs for ms in b["device_edge_ms"].split(";")]
    after = [float(ms) for _, c in pairs for ms in c["device_edge_ms"].split(";")]
    lines.append(paired_row("each device's median ms a device-slot, device by device",
                            before, after))
    if looks:
        lines.append(paired_row("a merge look's median ms (beside the slots)",
                                [float(b["look_ms_median"]) for b, _ in pairs],
                                [float(c["look_ms_median"]) for _, c in pairs]))
    if merges:
        lines += _merge_rows(pairs)
    differ = sorted({f for b, c in pairs for f in SAME_WALK if b[f] != c[f]})
    if not differ:
        return [*lines, "", "The same walk in both trees: every other figure equal."]
    lines += ["", "Figures that differ between the trees: " + ", ".join(differ) + ".", "",
              "| the walk | the baseline (seed by seed) | this tree | difference |",
              "|---|---|---|---|"]
    for column, name, scale, fmt in WALK:
        lines.append(paired_row(name, [scale * float(b[column]) for b, _ in pairs],
                                [scale * float(c[column]) for _, c in pairs], fmt))
    lines.append(paired_row(
        "each device's ATE, cm, device by device",
        [100 * float(m) for b, _ in pairs for m in b["device_ate_m"].split(";")],
        [100 * float(m) for _, c in pairs for m in c["device_ate_m"].split(";")], "{:.2f}"))
    return lines


def _merge_rows(pairs: list[tuple[dict[str, str], dict[str, str]]]) -> list[str]:
    """The merges' slots paired device by device (the devices that merged in both trees;
    a place's first device merges into none), and a line of the trees' false merges and of
    the devices that merged in one tree only."""
    before, after, one_tree = [], [], 0
    for base, current in pairs:
        for b, c in zip(base["device_merge_slot"].split(";"),
                        current["device_merge_slot"].split(";"), strict=True):
            if int(b) >= 0 and int(c) >= 0:
                before.append(float(b))
                after.append(float(c))
            elif int(b) >= 0 or int(c) >= 0:
                one_tree += 1
    false = [sum(int(run["false_merges"]) for run in arm) for arm in zip(*pairs, strict=True)]
    return [paired_row("the slot of its walk each later device merged at, device by device",
                       before, after, "{:.0f}"),
            "", f"False merges: {false[0]} in the baseline, {false[1]} in this tree; devices "
            f"merged in one tree only: {one_tree}."]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("runs", type=Path, nargs="+",
                        help="bench.place_walks --baseline --csv tables, one a seed")
    parser.add_argument("--looks", action="store_true",
                        help="a row more: the merge looks' median worker ms, paired by seed")
    parser.add_argument("--merges", action="store_true",
                        help="a row more: each later device's merge slot, paired device by "
                        "device, and the false merges")
    args = parser.parse_args()
    print("\n".join(table(args.runs, args.looks, args.merges)))


if __name__ == "__main__":
    main()
