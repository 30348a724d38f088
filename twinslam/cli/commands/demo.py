"""``twinslam demo`` (what ``make run`` runs): the most complete real thing that exists today.

1. The live pipeline — sequence_player, device_tracker and edge_mapper as separate processes
   on a private ROS domain on this machine — with **the paper's device** (``map_source:
   edge``: every frame tracked only against the edge's last map), once per policy (LFF, PU,
   ADAPT) on the ``revisit-v15`` scenario: the first 300 real 7-Scenes frames of
   ``../shared/data`` forward then back (when that is missing, and then said so, the
   synthetic corridor of :mod:`twinslam.sequences.synthetic_worlds`: a place that never
   repeats, out of sight a few metres on) with an edge map of 15 keyframes, so what the edge
   kept decides whether the device tracks on the way back. A status line per slot, then per
   policy: tracking failures, relocalisations, untracked frames, ATE and RPE (evo), and the
   share of next-slot frames the simulator's rule predicts lost beside the share the device
   really failed. Each policy runs twice, side by side: with the paper's edge (what it evicts
   is gone for the device) and with the edge bringing keyframes back from its archive where
   the camera heads (:data:`ARCHIVE_RESTORES`, :mod:`edge_mapper.restores`).
2. The same with the Edge-SLAM style device (``edge+local``), which also tracks on its own
   recent points: the map hardly matters to it.
3. The offline simulator with LFF, PU, ADAPT and the clairvoyant reference on the covisibility
   the ORB front end extracted from 1000 real 7-Scenes frames (shipped in ``data/``), scored
   by the same rule of a lost frame (:mod:`twinslam.slot_protocol.lost_frame_rule`).
"""

from __future__ import annotations

import argparse
import time

from twinslam.cli.arguments import BUNDLED_COVIS, BUNDLED_SEQUENCE, FALLBACK_SEQUENCE
from twinslam.cli.commands.sim import Comparison, compare
from twinslam.cli.console import Subparsers
from twinslam.live.calibration import covisibility_file
from twinslam.live.launcher import DEFAULT_PARAMS
from twinslam.live.runs import RunKey, RunTask, run_one
from twinslam.live.scenarios import SCENARIOS
from twinslam.live.tables import side_by_side
from twinslam.node_hosts.fastdds import REPO_ROOT

#: what the demo's live runs play
SCENARIO = "revisit-v15"
#: the device's two map sources, as the demo introduces them
DEVICES = {"edge": "the paper's device (tracked only against the edge's map)",
           "edge+local": "the Edge-SLAM style device (edge map + its own recent points)"}
#: the edge variant the paper's device also runs with: archived keyframes brought back where
#: the camera heads, at most 3 a slot (measured on this walk: fewer frames lost on every seed;
#: docs/results/paper-device.md, "The edge's archive and restores")
ARCHIVE_RESTORES: tuple[str, tuple[str, ...]] = ("restores", ("restore_keyframes:=3",))
#: the edges each device runs with: (name in the table, edge parameters; "": the paper's)
EDGES: dict[str, list[tuple[str, tuple[str, ...]]]] = {
    "edge": [("", ()), ARCHIVE_RESTORES], "edge+local": [("", ())]}


def run_live(policies: list[str], frames: int, step: str, map_source: str) -> bool:
    """The live pipeline once per policy with the device's ``map_source``, calibrated against
    the simulator's view of the same frames; True when every run scored slots."""
    if BUNDLED_SEQUENCE.is_dir():
        sequence, what = str(BUNDLED_SEQUENCE), f"{frames} real 7-Scenes frames"
    else:
        sequence, what = f"{FALLBACK_SEQUENCE}:{frames}", (
            f"{frames} frames of the synthetic corridor ({BUNDLED_SEQUENCE} is missing)")
    chosen = SCENARIOS[SCENARIO]
    edges = {variant: f"the edge {variant} ({', '.join(params)})" if variant
             else "the paper's edge" for variant, params in EDGES[map_source]}
    print(f"{step} live pipeline (player, device, edge as processes on a loopback domain), "
          f"{DEVICES[map_source]}, {what}, scenario {SCENARIO} ({chosen.description}), "
          f"policies {', '.join(policies)}, each with {' and '.join(edges.values())}",
          flush=True)
    covis = covisibility_file(sequence, frames, REPO_ROOT / "results" / "demo" / "covis",
                              lambda line: print("      " + line, flush=True))
    results = []
    for policy in policies:
        for variant, params in EDGES[map_source]:
            if len(edges) > 1:               # the status lines below say the policy, not this
                print(f"      {policy}, {edges[variant]}:", flush=True)
            results.append(run_one(RunTask(
                RunKey(SCENARIO, map_source, policy, 0), sequence, frames, chosen,
                DEFAULT_PARAMS, 600.0, covis, verbose=True, edge_params=params,
                edge_variant=variant)))
    print()
    for line in side_by_side(results):
        print("      " + line)
    return all(r.report.slots > 0 for r in results)


def run(args: argparse.Namespace) -> int:
    start = time.monotonic()
    graph_ok = run_live(["lff", "pu", "adapt"], args.frames, "[1/3]", "edge")
    graph_ok &= run_live(["lff", "pu", "adapt"], args.frames, "\n[2/3]", "edge+local")
    if BUNDLED_COVIS.is_file():
        covis, what = str(BUNDLED_COVIS), ("real covisibility: ORB map points of 1000 7-Scenes "
                                           "frames (data/)")
    else:
        covis, what = "geometric:600", f"the geometric room model ({BUNDLED_COVIS} is missing)"
    print(f"\n[3/3] offline simulator, {args.slots} slots x {args.seeds} seeds — {what}",
          flush=True)
    code = compare(Comparison(covis, slots=args.slots, seeds=args.seeds))
    print(f"\ndemo finished in {time.monotonic() - start:.0f} s")
    return 0 if graph_ok and code == 0 else 1


def register(sub: Subparsers) -> None:
    demo = sub.add_parser("demo", help="the live pipeline per policy with the paper's device "
                          "and the Edge-SLAM style one, then the simulator")
    demo.add_argument("--frames", type=int, default=300,
                      help="frames of the sequence the live runs play forward and back "
                      "(2x-1 played); default %(default)s")
    demo.add_argument("--slots", type=int, default=40, help="simulator slots per run")
    demo.add_argument("--seeds", type=int, default=3, help="simulator runs per policy")
    demo.set_defaults(func=run)
