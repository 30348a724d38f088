"""``make run``: the most complete real thing that exists today.

1. The live pipeline — sequence_player, device_tracker and edge_mapper as separate processes
   on a private ROS domain on this machine — once per policy (LFF, PU, ADAPT) on the first 600 real
   7-Scenes frames of ``../shared/data`` (the synthetic room when that is missing, and then
   said so), with a status line per slot and a table per policy at the end: mean υ, lost
   next-slot frames, ATE and RPE (evo), uploads, MB, achieved uplink throughput, untracked
   frames, tracking failures, relocalisations, time to recover, edge ms per slot.
2. The same on the ``revisit-lost`` scenario (:mod:`twinslam.cli.scenarios`): the first half
   of those frames forward then back, the lens covered for 3 s on the way back, so the device
   must relocalise against the edge's map — the case where the kept keyframes matter.
3. The offline simulator with LFF, PU, ADAPT and the clairvoyant reference on the covisibility
   the ORB front end extracted from 1000 real 7-Scenes frames (shipped in ``data/``).
"""

from __future__ import annotations

import argparse
import time

from twinslam.node_hosts.fastdds import REPO_ROOT
from twinslam.node_hosts.loopback import LoopbackDomain

REPO = REPO_ROOT
REAL_COVIS = REPO / "data" / "7scenes-redkitchen-1000.covis.npz"
REAL_SEQUENCE = REPO.parent / "shared" / "data" / "7scenes-1000"


def run_pipeline(policies: list[str], frames: int, step: str, scenario: str = "forward"
                 ) -> bool:
    from twinslam.cli.launcher import LaunchConfig, Launcher, RunReport, print_table
    from twinslam.cli.scenarios import SCENARIOS

    if REAL_SEQUENCE.is_dir():
        sequence, what = str(REAL_SEQUENCE), f"{frames} real 7-Scenes frames"
    else:
        sequence, what = f"synthetic:{frames}", (f"{frames} synthetic frames ({REAL_SEQUENCE} "
                                                 "is missing)")
    chosen = SCENARIOS[scenario]
    print(f"{step} live pipeline (player, device, edge as processes on a loopback domain), "
          f"{what}, scenario {scenario} ({chosen.description}), policies "
          f"{', '.join(policies)}", flush=True)
    reports: list[RunReport] = []
    for policy in policies:
        with LoopbackDomain() as dom:
            dom.activate()
            config = LaunchConfig(sequence, policy, frames, scenario=chosen)
            reports.append(Launcher(dom, config,
                                    lambda line: print("      " + line, flush=True)).run())
    print()
    print_table(reports, lambda line: print("      " + line))
    return all(r.slots > 0 for r in reports)


def run_demo(args: argparse.Namespace) -> int:
    start = time.monotonic()
    graph_ok = run_pipeline(["lff", "pu", "adapt"], args.frames, "[1/3]")
    graph_ok &= run_pipeline(["lff", "pu", "adapt"], args.frames // 2, "\n[2/3]",
                             "revisit-lost")
    if REAL_COVIS.is_file():
        covis, what = str(REAL_COVIS), ("real covisibility: ORB map points of 1000 7-Scenes "
                                        "frames (data/)")
    else:
        covis, what = "geometric:600", f"the geometric room model ({REAL_COVIS} is missing)"
    print(f"\n[3/3] offline simulator, {args.slots} slots x {args.seeds} seeds — {what}",
          flush=True)
    from twinslam.cli.main import main

    code = main(["sim", "--policy", "lff,pu,adapt,reference", "--covis", covis,
                 "--slots", str(args.slots), "--seeds", str(args.seeds)])
    print(f"\ndemo finished in {time.monotonic() - start:.0f} s")
    return 0 if graph_ok and code == 0 else 1
