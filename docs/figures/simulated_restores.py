"""The simulator's yardstick with restores (docs/results.md, "The simulator's yardstick with
restores"): each policy on the paper's edge, which forgets what it evicts, beside its variant on
an edge with an archive it may restore from, on the same episodes (``twinslam sim --csv`` of
the same --covis, --seeds, --slots and channel; each command is in results.md beside its
table).

    .venv/bin/python docs/figures/simulated_restores.py PAPER_EDGE.csv ARCHIVE.csv

A row pairs a policy of the paper's edge with its variant on the archive's edge:
``restore:POLICY`` with ``POLICY``, and ``mpc`` and ``reference`` (which plan restores where
there is an archive) with themselves. Per side: the lost share and mean υ (a lost frame
scoring 0) as mean ± 95 % CI over the episodes, υ over the tracked frames, and restores a
run; then the paired differences archive − paper edge on the same episodes with their
Student-t intervals (twinslam.reporting.paired_difference).
"""

from __future__ import annotations

import argparse
import csv
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from twinslam.reporting import mean_ci95, paired_difference

RESTORE_PREFIX = "restore:"


@dataclass(frozen=True)
class Episode:
    mean: float          #: mean υ of the run, a lost frame scoring 0
    lost: float          #: share of next-slot frames lost
    tracked: float       #: υ over the tracked frames
    restored: int        #: archived keyframes brought back


def read_runs(path: Path) -> dict[str, dict[int, Episode]]:
    """policy → seed → its run, from a ``twinslam sim --csv`` file."""
    out: dict[str, dict[int, Episode]] = {}
    with path.open(encoding="utf-8") as fh:
        for row in csv.DictReader(fh):
            out.setdefault(row["policy"], {})[int(row["seed"])] = Episode(
                float(row["mean_uncertainty"]), float(row["lost_share"]),
                float(row["tracked_uncertainty"]), int(row.get("restored") or 0))
    return out


def paper_policy(name: str) -> str:
    """The paper's-edge policy an archive-edge policy is the variant of."""
    return name[len(RESTORE_PREFIX):] if name.startswith(RESTORE_PREFIX) else name


def _ci(values: list[float], scale: float = 1.0, digits: int = 1) -> str:
    mean, half = mean_ci95(values)
    return f"{scale * mean:.{digits}f} ± {scale * half:.{digits}f}"


def _paired(archive: list[float], paper: list[float], scale: float = 1.0,
            digits: int = 1) -> str:
    d = paired_difference(np.asarray(archive)[None, :], paper)
    return (f"{scale * d.mean:+.{digits}f} [{scale * d.low:+.{digits}f}, "
            f"{scale * d.high:+.{digits}f}]")


def table(paper: dict[str, dict[int, Episode]], archive: dict[str, dict[int, Episode]]
          ) -> list[str]:
    """The markdown rows: one per archive-edge policy whose paper's-edge policy ran on the
    same seeds."""
    lines = ["| policy (paper's edge → with the archive) | episodes | lost % paper's edge "
             "| lost % with archive | Δ lost (points) | mean υ paper's edge | mean υ with "
             "archive | Δ mean υ | υ tracked paper's edge | υ tracked with archive "
             "| restores a run |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for name, runs in archive.items():
        base = paper.get(paper_policy(name))
        if base is None:
            continue
        seeds = sorted(runs)
        if sorted(base) != seeds:
            raise SystemExit(f"{name}: seeds {seeds} on the archive's edge, "
                             f"{sorted(base)} on the paper's: not the same episodes")
        a = [runs[s] for s in seeds]
        p = [base[s] for s in seeds]
        label = (f"{paper_policy(name)} → {name}" if name != paper_policy(name) else name)
        lines.append(
            f"| {label} | {len(seeds)} | {_ci([e.lost for e in p], 100)} "
            f"| {_ci([e.lost for e in a], 100)} "
            f"| {_paired([e.lost for e in a], [e.lost for e in p], 100)} "
            f"| {_ci([e.mean for e in p])} | {_ci([e.mean for e in a])} "
            f"| {_paired([e.mean for e in a], [e.mean for e in p])} "
            f"| {_ci([e.tracked for e in p])} | {_ci([e.tracked for e in a])} "
            f"| {np.mean([e.restored for e in a]):.1f} |")
    if len(lines) == 2:
        raise SystemExit("no policy of the archive's file has its paper's-edge policy in the "
                         "other file")
    return lines


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("paper_edge", type=Path, help="twinslam sim --csv of the paper's edge")
    parser.add_argument("archive", type=Path,
                        help="twinslam sim --csv of the same episodes with --archive-keyframes")
    args = parser.parse_args(argv)
    for line in table(read_runs(args.paper_edge), read_runs(args.archive)):
        print(line)


if __name__ == "__main__":
    main(sys.argv[1:])
