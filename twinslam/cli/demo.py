"""``make run``: the most complete real thing that exists today.

1. The live pipeline — sequence_player, device_tracker and edge_mapper as separate processes
   on a private ROS domain on this machine — with **the paper's device** (``map_source:
   edge``: every frame tracked only against the edge's last map), once per policy (LFF, PU,
   ADAPT) on the ``revisit-v15`` scenario: the first 300 real 7-Scenes frames of
   ``../shared/data`` forward then back (the synthetic room when that is missing, and then
   said so) with an edge map of 15 keyframes, so what the edge kept decides whether the
   device tracks on the way back. A status line per slot, then per policy: tracking failures,
   relocalisations, untracked frames, ATE and RPE (evo), and the share of next-slot frames the
   simulator's rule predicts lost beside the share the device really failed.
2. The same with the Edge-SLAM style device (``edge+local``), which also tracks on its own
   recent points: the map hardly matters to it.
3. The offline simulator with LFF, PU, ADAPT and the clairvoyant reference on the covisibility
   the ORB front end extracted from 1000 real 7-Scenes frames (shipped in ``data/``), scored
   by the same rule of a lost frame (:mod:`twinslam.common.tracking_rule`).
"""

from __future__ import annotations

import argparse
import time

from twinslam.node_hosts.fastdds import REPO_ROOT

REPO = REPO_ROOT
REAL_COVIS = REPO / "data" / "7scenes-redkitchen-1000.covis.npz"
REAL_SEQUENCE = REPO.parent / "shared" / "data" / "7scenes-1000"
#: what the demo's live runs play
SCENARIO = "revisit-v15"


def run_live(policies: list[str], frames: int, step: str, map_source: str) -> bool:
    """The live pipeline once per policy with the device's ``map_source``, calibrated against
    the simulator's view of the same frames; True when every run scored slots."""
    from twinslam.cli.evaluate import RunKey, RunTask, run_one, side_by_side
    from twinslam.cli.launcher import DEFAULT_PARAMS
    from twinslam.cli.live_calibration import covisibility_file
    from twinslam.cli.scenarios import SCENARIOS

    if REAL_SEQUENCE.is_dir():
        sequence, what = str(REAL_SEQUENCE), f"{frames} real 7-Scenes frames"
    else:
        sequence, what = f"synthetic:{frames}", (f"{frames} synthetic frames ({REAL_SEQUENCE} "
                                                 "is missing)")
    chosen = SCENARIOS[SCENARIO]
    device = {"edge": "the paper's device (tracked only against the edge's map)",
              "edge+local": "the Edge-SLAM style device (edge map + its own recent points)"}
    print(f"{step} live pipeline (player, device, edge as processes on a loopback domain), "
          f"{device[map_source]}, {what}, scenario {SCENARIO} ({chosen.description}), "
          f"policies {', '.join(policies)}", flush=True)
    covis = covisibility_file(sequence, frames, REPO / "results" / "demo" / "covis",
                              lambda line: print("      " + line, flush=True))
    results = [run_one(RunTask(RunKey(SCENARIO, map_source, policy, 0), sequence, frames,
                               chosen, DEFAULT_PARAMS, 600.0, covis, verbose=True))
               for policy in policies]
    print()
    for line in side_by_side(results):
        print("      " + line)
    return all(r.report.slots > 0 for r in results)


def run_demo(args: argparse.Namespace) -> int:
    start = time.monotonic()
    graph_ok = run_live(["lff", "pu", "adapt"], args.frames, "[1/3]", "edge")
    graph_ok &= run_live(["lff", "pu", "adapt"], args.frames, "\n[2/3]", "edge+local")
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
