"""How much of one view two keyframes share, against how far apart their cameras stand
(docs/results/shared-map.md, "A copy's points held already"): for each CSV ``bench.view_overlap``
wrote, every pair's share of the second keyframe's features matched in the images, lying on
one of the first's corners, and welded, against the distance between the two cameras, one
panel a sequence; the covered view's 0.30 m marked.

    .venv/bin/python docs/figures/view_overlap_figure.py NAME=CSV [NAME=CSV ...] -o PNG
"""

from __future__ import annotations

import argparse
import csv
from pathlib import Path

from twinslam.reporting import pyplot

#: the shares drawn: (the CSV's column, its label, its marker)
SHARES = (("matched", "matched in the images", "o"),
          ("same_corner", "the same corner (2 cm, alike)", "s"),
          ("welded", "welded", "x"))
#: the covered view's distance bound (CoverageBounds.max_m), for the eye
COVERED_M = 0.30


def draw(runs: list[tuple[str, Path]], out: Path) -> None:
    """One panel a run: each share of every pair against its cameras' distance."""
    plt = pyplot()
    fig, axes = plt.subplots(1, len(runs), figsize=(5.2 * len(runs), 4.0), sharey=True,
                             squeeze=False)
    for ax, (name, path) in zip(axes[0], runs, strict=True):
        with path.open(encoding="utf-8", newline="") as fh:
            pairs = list(csv.DictReader(fh))
        for column, label, marker in SHARES:
            ax.scatter([float(p["apart_m"]) for p in pairs], [float(p[column]) for p in pairs],
                       s=14, marker=marker, alpha=0.6, label=label)
        ax.axvline(COVERED_M, color="grey", linestyle=":", linewidth=1)
        ax.set_title(name)
        ax.set_xlabel("cameras apart, m")
        ax.set_xlim(left=0.0)
        ax.grid(alpha=0.3)
    axes[0][0].set_ylabel("share of the second keyframe's features")
    axes[0][0].set_ylim(0.0, 1.02)
    axes[0][0].legend(loc="upper right", fontsize=8)
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    plt.close(fig)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("runs", nargs="+", metavar="NAME=CSV",
                        help="a panel's title and the CSV bench.view_overlap wrote")
    parser.add_argument("-o", "--out", type=Path, required=True, help="the PNG written")
    args = parser.parse_args()
    runs = []
    for run in args.runs:
        name, sep, path = run.partition("=")
        if not sep or not Path(path).is_file():
            parser.error(f"{run!r}: NAME=CSV, the CSV a file")
        runs.append((name, Path(path)))
    draw(runs, args.out)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
