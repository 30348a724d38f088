"""The covered view's bounds against what they save and what they cost (docs/results/shared-map.md,
"The bounds of a covered view"): ``bench.place_walks`` runs at several ``--covered-m`` /
``--covered-deg`` pairs, beside the devices alone. Draws, bound by bound and seed by seed,
the uploads of the devices after the first as a share of theirs alone (the same seed), the
frames their maps did not serve and the edge's median ms a device-slot, the devices alone
first; prints the same as a table (mean over the seeds, and the seeds' range).

    .venv/bin/python docs/figures/covered_bounds_curve.py ALONE.csv BOUNDS.csv [BOUNDS.csv ...]
        [--figure PNG]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from place_walks_table import runs

from twinslam.reporting import pyplot

#: (what is drawn, its unit) for each panel, in order
PANELS = (("later devices' uploads, % of alone", "%"),
          ("frames the devices' maps did not serve", "%"),
          ("the edge's median ms a device-slot", "ms"))


def curve(alone_path: Path, bound_paths: list[Path]
          ) -> list[tuple[str, list[int], list[list[float]]]]:
    """The devices alone first, then per bounds file: its label, the seeds it shares with
    alone and each panel's values over them (a figure its runs lack is NaN)."""
    alone = runs(alone_path)
    out = []
    for path in [alone_path, *bound_paths]:
        arm = runs(path)
        seeds = sorted(arm.keys() & alone.keys())
        if not seeds:
            raise SystemExit(f"{path} shares no seed with {alone_path}")
        first = arm[seeds[0]]
        label = ("alone" if path == alone_path else
                 f"{float(first['covered_m']):g} m, {float(first['covered_deg']):g}°")
        values = [[100.0 * float(arm[s]["later_uploads"]) / float(alone[s]["later_uploads"])
                   for s in seeds],
                  [100.0 * float(arm[s].get("map_lost_share") or "nan") for s in seeds],
                  [float(arm[s]["edge_ms_median"]) for s in seeds]]
        out.append((label, seeds, values))
    return out


def table(points: list[tuple[str, list[int], list[list[float]]]]) -> list[str]:
    """A markdown row a bound: each panel's mean over the seeds and their range."""
    lines = ["| covered bounds | seeds | " + " | ".join(name for name, _ in PANELS) + " |",
             "|---|---|" + "---|" * len(PANELS)]
    for label, seeds, values in points:
        cells = []
        for column in values:
            a = np.asarray(column, dtype=float)
            cells.append("—" if np.isnan(a).all() else
                         f"{np.nanmean(a):.1f} ({np.nanmin(a):.1f}–{np.nanmax(a):.1f})")
        lines.append(f"| {label} | {', '.join(map(str, seeds))} | " + " | ".join(cells) + " |")
    return lines


def figure(points: list[tuple[str, list[int], list[list[float]]]], out: Path) -> Path:
    """One panel a figure, the bounds along x, a dot a seed and a bar at the mean."""
    plt = pyplot()
    fig, axes = plt.subplots(1, len(PANELS), figsize=(4.0 * len(PANELS), 3.6))
    for col, (ax, (name, unit)) in enumerate(zip(axes, PANELS, strict=True)):
        for x, (_, _, values) in enumerate(points):
            ys = np.asarray(values[col], dtype=float)
            ax.scatter([x] * len(ys), ys, color="tab:blue", alpha=0.7, s=18)
            if not np.isnan(ys).all():
                ax.hlines(np.nanmean(ys), x - 0.25, x + 0.25, color="black")
        ax.set_xticks(range(len(points)), [label for label, _, _ in points], fontsize=8)
        ax.set_title(name, fontsize=9)
        ax.set_ylabel(unit)
        ax.set_xlim(-0.6, len(points) - 0.4)
    fig.suptitle("the covered view's bounds, four devices along the corridor", fontsize=10)
    fig.tight_layout()
    fig.savefig(out, dpi=120)
    plt.close(fig)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("alone", type=Path, help="the devices alone (bench.place_walks "
                        "--no-merge --csv)")
    parser.add_argument("bounds", type=Path, nargs="+",
                        help="one CSV a pair of bounds (bench.place_walks --covered-m M "
                             "--covered-deg D --csv), drawn in this order")
    parser.add_argument("--figure", type=Path,
                        help="where to draw it (default: covered-bounds.png beside the first "
                             "bounds CSV)")
    args = parser.parse_args()
    points = curve(args.alone, args.bounds)
    print("\n".join(table(points)))
    out = figure(points, args.figure or args.bounds[0].parent / "covered-bounds.png")
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
