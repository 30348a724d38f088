"""The cross-device revisit error split in two, seed by seed: the one rigid motion of the
second device's frames that leaves it least (how far a better merge alignment could bring two
maps together) and what is left after it (the maps bending apart along the walks), beside
each device's error against itself on such pairs.

    .venv/bin/python docs/figures/cross_device_split_table.py NAME=CSV [NAME=CSV ...]
        [--figure PNG]

Each CSV is ``bench.shared_map --csv``'s (runs with the columns ``cross_rigid_left_rms_m``,
``cross_rigid_moved_m``, ``cross_rigid_turned_deg``); NAME labels its rows. Prints one
Markdown table, a row a run in seed order and a mean row a CSV; ``--figure`` draws each run
as a bar of its cross-device RMS, the part left after the best rigid motion below and the
rest above, beside the worse device's error against itself.
"""

from __future__ import annotations

import argparse
import csv
import math
import sys
from pathlib import Path

from twinslam.reporting import pyplot


def _cm(value: str) -> str:
    metres = float(value) if value else math.nan
    return "–" if math.isnan(metres) else f"{metres * 100:.1f}"


def _mean_cm(rows: list[dict[str, str]], column: str) -> str:
    values = [float(r[column]) for r in rows if r.get(column)]
    return f"{sum(values) / len(values) * 100:.1f}" if values else "–"


def table(named: list[tuple[str, Path]]) -> list[str]:
    """The table's lines for each (name, CSV) in order."""
    lines = ["| scenario | seed | merged at slot | cross-device RMS (cm) | best rigid motion "
             "(cm, °) | left after it (cm) | rigid share of the squared error | first device "
             "against itself (cm) | second device against itself (cm) |",
             "|---|---|---|---|---|---|---|---|---|"]
    for name, path in named:
        with path.open(newline="", encoding="utf-8") as fh:
            rows = sorted(csv.DictReader(fh), key=lambda r: int(r["seed"]))
        if not rows:
            raise SystemExit(f"{path}: no runs")
        lacking = [c for c in ("cross_rigid_left_rms_m", "cross_rigid_moved_m")
                   if c not in rows[0]]
        if lacking:
            raise SystemExit(f"{path}: no column {', '.join(lacking)} (a bench.shared_map "
                             "from before the split)")
        for r in rows:
            whole, left = float(r["cross_rms_m"]), float(r["cross_rigid_left_rms_m"])
            share = 1.0 - (left / whole) ** 2 if whole > 0 else math.nan
            lines.append(f"| {name} | {r['seed']} | {r['merge_slot']} | {_cm(r['cross_rms_m'])} "
                         f"| {_cm(r['cross_rigid_moved_m'])}, "
                         f"{float(r['cross_rigid_turned_deg']):.2f} | "
                         f"{_cm(r['cross_rigid_left_rms_m'])} | {share:.0%} | "
                         f"{_cm(r['first_self_rms_m'])} | {_cm(r['second_self_rms_m'])} |")
        lines.append(f"| {name}, mean of {len(rows)} |  |  | {_mean_cm(rows, 'cross_rms_m')} | "
                     f"{_mean_cm(rows, 'cross_rigid_moved_m')} | "
                     f"{_mean_cm(rows, 'cross_rigid_left_rms_m')} |  | "
                     f"{_mean_cm(rows, 'first_self_rms_m')} | "
                     f"{_mean_cm(rows, 'second_self_rms_m')} |")
    return lines


def figure(named: list[tuple[str, Path]], out: Path) -> Path:
    """Each run's cross-device RMS as a bar — the error left after the best rigid motion
    below, the rest of it above — with the worse device's error against itself as a tick;
    the runs in the CSVs' order, each CSV's in seed order."""
    plt = pyplot()
    labels, left, whole, selves = [], [], [], []
    for name, path in named:
        with path.open(newline="", encoding="utf-8") as fh:
            for r in sorted(csv.DictReader(fh), key=lambda r: int(r["seed"])):
                labels.append(f"{name}\nseed {r['seed']}")
                left.append(float(r["cross_rigid_left_rms_m"]) * 100)
                whole.append(float(r["cross_rms_m"]) * 100)
                selves.append((float(r["first_self_rms_m"]) * 100,
                               float(r["second_self_rms_m"]) * 100))
    x = list(range(len(labels)))
    fig, ax = plt.subplots(figsize=(max(6.0, 0.55 * len(x)), 4.2))
    ax.bar(x, left, color="tab:blue", label="left after the best rigid motion")
    ax.bar(x, [w - lo for w, lo in zip(whole, left, strict=True)], bottom=left,
           color="tab:orange", label="what that rigid motion takes out")
    ax.scatter(x, [max(s) for s in selves], marker="_", s=300, color="black",
               label="the worse device against itself", zorder=3)
    ax.set_xticks(x, labels, rotation=90, fontsize=7)
    ax.set_ylabel("cross-device revisit error RMS (cm)")
    ax.legend(fontsize=8, loc="upper right")
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out


def _named(arg: str) -> tuple[str, Path]:
    name, sep, path = arg.partition("=")
    if not sep or not name or not path:
        raise argparse.ArgumentTypeError(f"{arg!r}: give NAME=CSV")
    if not Path(path).is_file():
        raise argparse.ArgumentTypeError(f"{path}: no such file")
    return name, Path(path)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("runs", nargs="+", type=_named, metavar="NAME=CSV",
                        help="a label and a bench.shared_map --csv file of runs")
    parser.add_argument("--figure", type=Path, metavar="PNG",
                        help="also draw the runs' split into this file")
    args = parser.parse_args(argv)
    print("\n".join(table(args.runs)))
    if args.figure:
        print(f"wrote {figure(args.runs, args.figure)}")


if __name__ == "__main__":
    main(sys.argv[1:])
