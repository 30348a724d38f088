"""Were the loops the edge closed true? For each loop in a run's log (``runs/RUN.log`` of a
``twinslam evaluate`` folder), where the two keyframes truly were: the distance between the
two cameras and the angle between their gazes, from the walk's ground truth (keyframe ids are
frame indices). A loop between cameras metres apart, or looking different ways, joined two
places that only looked alike.

    .venv/bin/python docs/figures/loop-closing/loop_truth.py \\
        docs/figures/loop-closing/corridor-loops/runs/forward-lte_edge+local_lff_s4.log \\
        --sequence synthetic-corridor:5400:4 [--csv FILE]
"""

from __future__ import annotations

import argparse
import csv
import math
import re
from pathlib import Path

import numpy as np

from twinslam.sequences.opening import open_sequence

#: the edge's log line of an applied or refused loop (edge_mapper/device_link.py)
CLOSED = re.compile(r"slot (\d+): loop closed between keyframes (\d+) and (\d+) \((\d+) inliers\)"
                    r", the map moved up to ([\d.]+) m")
REFUSED = re.compile(r"slot (\d+): loop between keyframes (\d+) and (\d+) refused, (.*)$")
#: a loop whose cameras were this close and looked this alike saw the same place
SAME_PLACE_M = 1.0
SAME_GAZE_DEG = 45.0


def loops_in(log: str) -> list[dict[str, object]]:
    """The loops a run's log reports, applied or refused, in order."""
    out: list[dict[str, object]] = []
    for line in log.splitlines():
        if m := CLOSED.search(line):
            out.append({"slot": int(m[1]), "old": int(m[2]), "new": int(m[3]),
                        "inliers": int(m[4]), "moved_m": float(m[5]), "applied": 1})
        elif m := REFUSED.search(line):
            out.append({"slot": int(m[1]), "old": int(m[2]), "new": int(m[3]),
                        "inliers": math.nan, "moved_m": math.nan, "applied": 0})
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("log", type=Path, help="a run's log (runs/RUN.log of an evaluate folder)")
    parser.add_argument("--sequence", required=True,
                        help="the walk the run played, with its seed for a synthetic one "
                             "(synthetic-corridor:5400:4)")
    parser.add_argument("--csv", type=Path, default=None, help="write the rows here too")
    args = parser.parse_args()
    if not args.log.is_file():
        raise SystemExit(f"{args.log}: no such log")
    loops = loops_in(args.log.read_text(encoding="utf-8"))
    if not loops:
        raise SystemExit(f"{args.log}: no loop reported")
    last = max(max(int(str(x["old"])), int(str(x["new"]))) for x in loops) + 1
    poses = getattr(open_sequence(args.sequence, 0, last), "poses", None)
    if poses is None or any(p is None for p in poses):
        raise SystemExit(f"{args.sequence}: a walk whose every true pose is known is needed")
    rows = []
    for loop in loops:
        a, b = poses[int(str(loop["old"]))], poses[int(str(loop["new"]))]
        apart = float(np.linalg.norm(a[:3, 3] - b[:3, 3]))
        gaze = math.degrees(math.acos(float(np.clip(a[:3, 2] @ b[:3, 2], -1.0, 1.0))))
        same = apart <= SAME_PLACE_M and gaze <= SAME_GAZE_DEG
        rows.append({**loop, "apart_m": round(apart, 3), "gaze_deg": round(gaze, 1),
                     "same_place": int(same)})
    head = list(rows[0])
    print("| " + " | ".join(head) + " |\n|" + "---|" * len(head))
    for row in rows:
        print("| " + " | ".join(str(row[k]) for k in head) + " |")
    true = sum(int(str(r["same_place"])) for r in rows if r["applied"])
    applied = sum(int(str(r["applied"])) for r in rows)
    print(f"\n{applied} loops applied, {true} between cameras within {SAME_PLACE_M:g} m and "
          f"{SAME_GAZE_DEG:g}° of each other")
    if args.csv is not None:
        with args.csv.open("w", newline="", encoding="utf-8") as fh:
            writer = csv.DictWriter(fh, head)
            writer.writeheader()
            writer.writerows(rows)


if __name__ == "__main__":
    main()
