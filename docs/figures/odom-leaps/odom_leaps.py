"""Which frames make the ``odom`` pose leap: one live run of the default device, then the
frames whose ``odom`` step went furthest beyond the truth's step, each with what the device
said of it (a new map version, a relocalisation, a PnP-RANSAC pose, its inliers of its
matches) and the step of its ``map`` pose beside it.

    .venv/bin/python docs/figures/odom-leaps/odom_leaps.py [--frames 1000] [--seed 0] \\
        [--scenario revisit-v15@lte] [--params config/twinslam.yaml] [--top 15] [--csv OUT]

A leap the ``map`` pose makes too, on a frame the device flagged as no correction, is the
tracker's own (its pose solve jumped on the same map); one only the ``odom`` pose makes is the
odom frame's rule (:mod:`device_tracker.odometry_frame`) carrying a wrong step across a
correction.
"""

from __future__ import annotations

import argparse
import csv
import itertools
import sys
from pathlib import Path

import numpy as np

from msg_schemas.headers import time_key
from twinslam.cli.console import HelpFormatter
from twinslam.hosts.loopback import LoopbackDomain
from twinslam.live.launcher import DEFAULT_PARAMS, LaunchConfig, Launcher
from twinslam.live.report import frame_stamps
from twinslam.live.run_log import RunLog
from twinslam.live.scenarios import scenario as scenario_named

REPO = Path(__file__).resolve().parents[3]
SEQUENCE = REPO.parent / "shared" / "data" / "7scenes-1000"
FIELDS = ["frame", "odom_excess_mm", "map_excess_mm", "true_step_mm", "new_map_version",
          "relocalised", "after_untracked", "pnp_ransac", "inliers", "matches"]


def leaps(record: RunLog) -> list[dict[str, float]]:
    """One row per pair of consecutive tracked frames: the odom and map steps beyond the
    truth's (mm) and the flags of the second frame."""
    frames = {time_key(f.stamp): f for s in record.summaries.values() for f in s.frames}
    stamps = frame_stamps(record)
    rows = []
    for i, (a, b) in enumerate(itertools.pairwise(stamps)):
        fa, fb = frames.get(a), frames.get(b)
        if fa is None or fb is None or not (fa.tracked and fb.tracked):
            continue
        if not all(s in d for s in (a, b) for d in (record.odom_poses, record.poses,
                                                  record.ground_truth)):
            continue

        def step(poses: dict[int, np.ndarray], x: int = a, y: int = b) -> float:
            return float(np.linalg.norm(poses[y][:3, 3] - poses[x][:3, 3])) * 1000.0
        truth = step(record.ground_truth)
        before = frames.get(stamps[i - 1]) if i > 0 else None
        rows.append({"frame": int(fb.frame_id), "odom_excess_mm": step(record.odom_poses) - truth,
                     "map_excess_mm": step(record.poses) - truth, "true_step_mm": truth,
                     "new_map_version": int(fb.map_version != fa.map_version),
                     "relocalised": int(fb.relocalised),
                     "after_untracked": int(before is not None and not before.tracked),
                     "pnp_ransac": int(fb.pnp_ransac), "inliers": int(fb.inliers),
                     "matches": int(fb.matches)})
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=HelpFormatter)
    parser.add_argument("--sequence", default=str(SEQUENCE), help="the RGB-D sequence played")
    parser.add_argument("--frames", type=int, default=1000, help="frames played")
    parser.add_argument("--seed", type=int, default=0, help="the uplink's seed")
    parser.add_argument("--scenario", default="revisit-v15@lte", help="the run's scenario")
    parser.add_argument("--params", type=Path, default=DEFAULT_PARAMS,
                        help="the nodes' parameter file (default: the default device's)")
    parser.add_argument("--top", type=int, default=15, help="the largest leaps listed")
    parser.add_argument("--csv", type=Path, default=None, help="write every pair's row here")
    args = parser.parse_args()
    config = LaunchConfig(args.sequence, "lff", args.frames, params_file=args.params,
                          scenario=scenario_named(args.scenario),
                          extra={"device_tracker": [f"seed:={args.seed}"]}, timeout_s=900.0)
    with LoopbackDomain() as dom:
        dom.activate()
        launcher = Launcher(dom, config, echo=None)
        report = launcher.run()
    if launcher.record is None:
        sys.exit("the run recorded nothing")
    rows = leaps(launcher.record)
    print(f"{len(rows)} pairs of tracked frames; camera frames dropped: {report.frames_dropped}")
    print("| frame | odom step beyond truth (mm) | map step beyond truth (mm) | true step (mm) "
          "| new map version | relocalised | after untracked | PnP RANSAC | inliers / matches |")
    print("|---|---|---|---|---|---|---|---|---|")
    for r in sorted(rows, key=lambda r: -r["odom_excess_mm"])[:args.top]:
        print(f"| {r['frame']} | {r['odom_excess_mm']:.1f} | {r['map_excess_mm']:.1f} | "
              f"{r['true_step_mm']:.1f} | {r['new_map_version']} | {r['relocalised']} | "
              f"{r['after_untracked']} | {r['pnp_ransac']} | {r['inliers']} / {r['matches']} |")
    if args.csv is not None:
        with args.csv.open("w", newline="", encoding="utf-8") as fh:
            writer = csv.DictWriter(fh, fieldnames=FIELDS)
            writer.writeheader()
            writer.writerows(rows)


if __name__ == "__main__":
    main()
