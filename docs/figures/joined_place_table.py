"""Two devices of one place, the second's map joined into the first's against lent copies
(docs/results/shared-map.md, "One map a place"): ``bench.shared_map`` runs, one CSV an arm
(``--join``; ``--share --share-both --no-checkpoints``), paired by seed — less a seed whose
runs repeat an earlier seed's in every arm (two seeds can draw one uplink). Prints a markdown
table — each figure seed by seed in both arms and the paired difference (joined − lent,
Student's t, :func:`twinslam.reporting.paired_row`) — and, given the runs alone
(``--no-merge``), the second device's uploads saved against them in each arm.

    .venv/bin/python docs/figures/joined_place_table.py LENT.csv JOINED.csv [--alone A.csv]
        [--lost] [--names "BASE NAME,JOINED NAME"]

``--names`` names the two arms where the first is not lending (two joined arms of different
code: the base and the one compared with it).
"""

from __future__ import annotations

import argparse
import csv
import math
from pathlib import Path

from shared_uplink_table import distinct_seeds

from twinslam.reporting import paired_row

#: (column, name in the table, scale, format)
FIGURES = [
    ("cross_rms_m", "cross-device revisit error, RMS cm", 100.0, "{:.1f}"),
    ("keyframes_cross_rms_m", "the two devices' final keyframes apart, RMS cm", 100.0,
     "{:.1f}"),
    ("second_uploads", "the second device's keyframes uploaded", 1.0, "{:.0f}"),
    ("second_lost_share", "its frames the edge counts lost (%)", 100.0, "{:.1f}"),
    ("second_map_lost_share", "its frames its map did not serve (%)", 100.0, "{:.1f}"),
    ("second_ate_m", "its ATE, cm", 100.0, "{:.1f}"),
    ("first_uploads", "the first device's keyframes uploaded", 1.0, "{:.0f}"),
    ("first_lost_share", "its frames the edge counts lost (%)", 100.0, "{:.1f}"),
    ("first_ate_m", "its ATE, cm", 100.0, "{:.1f}"),
    ("first_edge_ms", "the edge's median ms a slot, the first device", 1.0, "{:.1f}"),
    ("second_edge_ms", "the edge's median ms a slot, the second device", 1.0, "{:.1f}"),
]


def by_seed(path: Path) -> dict[int, dict[str, str]]:
    """The CSV's runs by seed (a seed run twice: its last run)."""
    with path.open(newline="") as f:
        return {int(row["seed"]): row for row in csv.DictReader(f)}


def _value(row: dict[str, str], column: str, scale: float) -> float:
    text = row.get(column, "")
    return float(text) * scale if text not in ("", None) else math.nan


#: the arms' names when the first is lending
LENT_AND_JOINED = ("lent copies", "joined")


def _difference(names: tuple[str, str]) -> str:
    """The difference column's name: "joined − lent" for lending against the join, else
    the second arm's against the first's."""
    return "joined − lent" if names == LENT_AND_JOINED else "second − first"


def table(lent_csv: Path, joined_csv: Path, alone_csv: Path | None = None,
          names: tuple[str, str] = LENT_AND_JOINED, lost: bool = False) -> list[str]:
    """The markdown lines :func:`main` prints (``names``: the two arms', the base first;
    ``lost``: with the runs alone, the second device's lost share against them too)."""
    lent, joined = by_seed(lent_csv), by_seed(joined_csv)
    alone = by_seed(alone_csv) if alone_csv is not None else {}
    arms = {"lent": lent, "joined": joined, **({"alone": alone} if alone else {})}
    seeds = distinct_seeds(arms)
    lines = [f"seeds {', '.join(map(str, seeds))}", "",
             f"| figure | {names[0]} | {names[1]} | {_difference(names)} [95 % CI] |",
             "|---|---|---|---|"]
    for column, name, scale, fmt in FIGURES:
        before = [_value(lent[s], column, scale) for s in seeds]
        after = [_value(joined[s], column, scale) for s in seeds]
        if not any(math.isnan(x) for x in before + after):
            lines.append(paired_row(name, before, after, fmt))
    if not alone:
        return lines
    common = seeds
    base = [_value(alone[s], "second_uploads", 1.0) for s in common]
    lines += ["", f"the second device alone (seeds {', '.join(map(str, common))}) uploaded "
                  f"{', '.join(f'{x:.0f}' for x in base)}", "",
              "| the second device's uploads | alone | sharing | sharing − alone [95 % CI] |",
              "|---|---|---|---|"]
    for name, arm in ((names[0], lent), (names[1], joined)):
        got = [_value(arm[s], "second_uploads", 1.0) for s in common]
        saved = 1.0 - sum(got) / sum(base)
        lines.append(paired_row(f"{name}: {saved:.1%} fewer ({sum(got):.0f} against "
                                f"{sum(base):.0f})", base, got, "{:.0f}"))
    if lost:
        base = [_value(alone[s], "second_lost_share", 100.0) for s in common]
        lines += ["", "| the second device's frames the edge counts lost (%) | alone | sharing "
                      "| sharing − alone [95 % CI] |", "|---|---|---|---|"]
        for name, arm in ((names[0], lent), (names[1], joined)):
            got = [_value(arm[s], "second_lost_share", 100.0) for s in common]
            lines.append(paired_row(name, base, got, "{:.1f}"))
    return lines


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("lent", type=Path, help="the runs with lent copies (the base)")
    parser.add_argument("joined", type=Path, help="the runs with the map joined")
    parser.add_argument("--alone", type=Path,
                        help="the runs that never merged: the second device's uploads saved")
    parser.add_argument("--lost", action="store_true",
                        help="with --alone: the second device's lost share against alone too")
    parser.add_argument("--names", metavar="BASE,JOINED", default="lent copies,joined",
                        help="the two arms' names in the table (default: %(default)s)")
    args = parser.parse_args(argv)
    names = tuple(n.strip() for n in args.names.split(","))
    if len(names) != 2 or not all(names):
        parser.error(f"--names takes two names separated by a comma, got {args.names!r}")
    for path in (args.lent, args.joined, *([args.alone] if args.alone else [])):
        if not path.is_file():
            parser.error(f"{path}: no such CSV (bench.shared_map --csv writes one)")
    if args.lost and not args.alone:
        parser.error("--lost compares with the runs alone: give --alone too")
    print("\n".join(table(args.lent, args.joined, args.alone, (names[0], names[1]),
                           args.lost)))


if __name__ == "__main__":
    main()
