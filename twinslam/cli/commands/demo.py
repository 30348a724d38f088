"""``twinslam demo`` (what ``make run`` runs): the most complete real thing that exists today.

1. The live pipeline — sequence_player, device_tracker and edge_mapper as separate processes
   on a private ROS domain on this machine — with **the default device**
   (``config/twinslam.yaml``: 1 s slots, the edge's map and the device's own recent points,
   the edge bringing archived keyframes back where the camera heads; measured best on every
   uplink family, :mod:`twinslam.slot_protocol.default_device`), once per policy (LFF, the
   default, PU, ADAPT) on the ``revisit-v15`` scenario: the first 300 real 7-Scenes frames of
   ``../shared/data`` forward then back (when that is missing, and then said so, the
   synthetic corridor of :mod:`twinslam.sequences.synthetic_worlds`: a place that never
   repeats, out of sight a few metres on) with an edge map of 15 keyframes, so what the edge
   kept decides what the device tracks against on the way back. A status line per slot.
2. The same with **the paper's Table I device** (``config/paper-table1.yaml``: 2 s slots, only
   the edge's map), then one table of both devices side by side: tracking failures,
   relocalisations, ATE and RPE (evo), jumps, the largest aligned error, the jitter of the
   published pose beside the truth's, and the share of next-slot frames the simulator's rule
   predicts lost beside the share the device really failed.
3. The offline simulator with LFF, PU, ADAPT and the clairvoyant reference on the covisibility
   the ORB front end extracted from 1000 real 7-Scenes frames (shipped in ``data/``), scored
   by the same rule of a lost frame (:mod:`twinslam.slot_protocol.lost_frame_rule`).
"""

from __future__ import annotations

import argparse
import time
from dataclasses import dataclass
from pathlib import Path

from twinslam.cli.arguments import BUNDLED_COVIS, BUNDLED_SEQUENCE, FALLBACK_SEQUENCE
from twinslam.cli.commands.sim import Comparison, compare
from twinslam.cli.console import Subparsers
from twinslam.hosts.fastdds import REPO_ROOT
from twinslam.live.calibration.frames import covisibility_file
from twinslam.live.launcher import DEFAULT_PARAMS, PAPER_PARAMS, player_camera
from twinslam.live.runs import RunKey, RunResult, RunTask, run_one
from twinslam.live.scenarios import SCENARIOS
from twinslam.live.tables import side_by_side
from twinslam.slam.front_end.map_source import EDGE, EDGE_LOCAL

#: what the demo's live runs play
SCENARIO = "revisit-v15"
POLICIES = ("lff", "pu", "adapt")


@dataclass(frozen=True)
class Device:
    """One device the demo runs: its name in the table, parameter file and map source."""

    name: str
    params: Path
    map_source: str
    description: str


DEVICES = (
    Device("default", DEFAULT_PARAMS, EDGE_LOCAL, "the default device (1 s slots, the edge's "
           "map and its own recent points, restores; config/twinslam.yaml)"),
    Device("table-i", PAPER_PARAMS, EDGE, "the paper's Table I device (2 s slots, tracked "
           "only against the edge's map; config/paper-table1.yaml)"),
)


def run_live(device: Device, frames: int, step: str) -> list[RunResult]:
    """The live pipeline once per policy with ``device``, calibrated against the simulator's
    view of the same frames."""
    if BUNDLED_SEQUENCE.is_dir():
        sequence, what = str(BUNDLED_SEQUENCE), f"{frames} real 7-Scenes frames"
    else:
        sequence, what = f"{FALLBACK_SEQUENCE}:{frames}", (
            f"{frames} frames of the synthetic corridor ({BUNDLED_SEQUENCE} is missing)")
    chosen = SCENARIOS[SCENARIO]
    print(f"{step} live pipeline (player, device, edge as processes on a loopback domain), "
          f"{device.description}, {what}, scenario {SCENARIO} ({chosen.description}), "
          f"policies {', '.join(POLICIES)}", flush=True)
    covis = covisibility_file(sequence, frames, REPO_ROOT / "results" / "demo" / "covis",
                              lambda line: print("      " + line, flush=True),
                              colour_intrinsics=player_camera(device.params))
    return [run_one(RunTask(RunKey(SCENARIO, device.map_source, policy, 0), sequence, frames,
                            chosen, device.params, 600.0, covis, verbose=True,
                            variant=device.name))
            for policy in POLICIES]


def run(args: argparse.Namespace) -> int:
    start = time.monotonic()
    results: list[RunResult] = []
    for i, device in enumerate(DEVICES, 1):
        results += run_live(device, args.frames, ("" if i == 1 else "\n") + f"[{i}/3]")
    print("\n      both devices, side by side (jit mm: RMS of the second difference of the "
          "published positions; gt jit: the truth's over the same frames):")
    for line in side_by_side(results):
        print("      " + line)
    graph_ok = all(r.report.slots > 0 for r in results)
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
    demo = sub.add_parser("demo", help="the live pipeline per policy with the default device "
                          "and the paper's Table I device side by side, then the simulator")
    demo.add_argument("--frames", type=int, default=300,
                      help="frames of the sequence the live runs play forward and back "
                      "(2x-1 played); default %(default)s")
    demo.add_argument("--slots", type=int, default=40, help="simulator slots per run")
    demo.add_argument("--seeds", type=int, default=3, help="simulator runs per policy")
    demo.set_defaults(func=run)
