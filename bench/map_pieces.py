"""Slots whose edge map is in pieces, with the edge's ``connected_map`` off and on, side
by side: one default device and edge in one process over a walk, each seed twice.

    python -m bench.map_pieces [SEQUENCE] [--frames 1350] [--order backward]
        [--uplink table1] [--seeds 400 401 402] [--device NAME=VALUE ...] [--csv FILE]

A map in pieces (u(G) = +∞, DESIGN §2) is two covisibility graphs with no common point: every
frame of the next slot scores as lost, whatever the device tracked, and the keyframes of the
turn between the pieces are missing from the map a device would come back to. It happens
where the frames the policy uploads see nothing the map's keyframes see — the default rule
(LFF) uploads the slot's newest frames, and a camera that turns ~90° within a slot's second
(the synthetic corridor's far end, walked backward) leaves a slot's newest frames without a
point in common with the keyframes of the slot before — or where it evicts the keyframe that
ties a piece to the rest. ``connected_map`` (:mod:`twinslam.policies.connected_map`) mends
such a decision, only where the policy's would split the map.

Each run (:func:`bench.in_process.open_walk`, the loop closer in the caller: repeatable) prints
and writes to ``--csv`` one row a seed and arm: the slots after the first whose map was in
pieces, the edge's lost share (its lost-frame rule, every frame of a slot in pieces counted),
the device's own (frames it tracked on fewer than 15 of the map's points it held, or not at
all), the frames tracked, the uploads, the ATE, the slots mended and the step's time a slot
(median and longest; with ``connected_map`` on: the check every slot pays, and the mends).
A synthetic SEQUENCE named by its frame count alone (``synthetic-corridor:1350``) is walked
on each seed, as the uplink is.
"""

from __future__ import annotations

import argparse
import math
import tempfile
import time
from collections.abc import Collection, Mapping
from pathlib import Path
from typing import Any

import numpy as np

import edge_mapper.slot_planner as slot_planner
from bench.in_process import (
    add_device_option,
    open_walk,
    parameters_text,
    repeatable_edge,
    seeded_spec,
)
from twinslam.cli.console import HelpFormatter
from twinslam.live.tracking_quality import absolute_trajectory_error
from twinslam.node_runtime.math_threads import one_math_thread
from twinslam.policies.actions import MapAction, SlotObservation
from twinslam.reporting import append_csv_rows
from twinslam.sequence_player.playback import ORDERS

FIELDS = ["sequence", "order", "uplink", "seed", "device_params", "connected_map", "slots",
          "pieces_slots", "edge_lost_share", "device_lost_share", "frames_tracked", "frames",
          "uploads", "ate_m", "mended_slots", "check_ms_median", "check_ms_max", "seconds"]


def run(spec: str, frames: int, order: str, uplink: str, seed: int, connected: bool,
        device: Mapping[str, object] | None = None) -> dict[str, Any]:
    """One walk with ``connected_map`` set as ``connected`` (``device``: the device node's
    parameters that differ from its defaults): the CSV row."""
    mended: list[int] = []
    check_ms: list[float] = []
    # the planner's own name for the step, replaced for the walk to count what it mends
    mend = slot_planner.connected_action  # type: ignore[attr-defined]

    def counted(obs: SlotObservation, action: MapAction,
                stale: Collection[int] = frozenset()) -> MapAction:
        t0 = time.perf_counter()
        answer = mend(obs, action, stale)
        check_ms.append((time.perf_counter() - t0) * 1e3)
        if answer is not action:
            mended.append(obs.slot)
        return answer

    slot_planner.connected_action = counted  # type: ignore[attr-defined]
    started = time.perf_counter()
    try:
        with tempfile.TemporaryDirectory() as folder:
            walk = open_walk("device", seeded_spec(spec, seed), frames, order, seed, uplink,
                             repeatable_edge(connected_map=connected), 8, Path(folder),
                             device_params=device)
            pieces: list[int] = []
            serve = walk.serve

            def watched(*args):  # type: ignore[no-untyped-def]
                served = serve(*args)
                if served.outcome.slot > 0 and not math.isfinite(
                        served.outcome.map_uncertainty):
                    pieces.append(served.outcome.slot)
                return served

            walk.serve = watched
            played = 0
            while walk.step() is not None:
                played += 1
    finally:
        slot_planner.connected_action = mend  # type: ignore[attr-defined]
    return {"sequence": spec, "order": order, "uplink": uplink, "seed": seed,
            "device_params": parameters_text((device or {}).items()),
            "connected_map": int(connected), "slots": walk.slot + 1,
            "pieces_slots": len(pieces), "edge_lost_share": float(np.nanmean(walk.lost)),
            "device_lost_share": walk.map_lost_share(), "frames_tracked": len(walk.poses),
            "frames": played, "uploads": walk.uploads,
            "ate_m": absolute_trajectory_error(walk.poses, walk.truth),
            "mended_slots": len(mended),
            "check_ms_median": float(np.median(check_ms)) if check_ms else math.nan,
            "check_ms_max": max(check_ms, default=math.nan),
            "seconds": round(time.perf_counter() - started, 1)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0],
                                     epilog=__doc__.split("\n", 2)[2],
                                     formatter_class=HelpFormatter)
    parser.add_argument("sequence", nargs="?", default="synthetic-corridor:1350",
                        help="the walk (a sequence the player reads; default: the synthetic "
                             "corridor, 1350 frames, walked on each seed)")
    parser.add_argument("--frames", type=int, default=1350, help="frames to play")
    parser.add_argument("--order", choices=ORDERS, default="backward",
                        help="the frames' order (default: from the walk's far end)")
    parser.add_argument("--uplink", default="table1",
                        help="uplink family (table1, lte, mmwave, constrained)")
    parser.add_argument("--seeds", type=int, nargs="+", default=[400, 401, 402],
                        help="the uplinks' seeds, and a synthetic walk's")
    add_device_option(parser)
    parser.add_argument("--csv", type=Path, help="append one row a seed and arm here")
    args = parser.parse_args()
    one_math_thread()
    rows = []
    for seed in args.seeds:
        for connected in (False, True):
            row = run(args.sequence, args.frames, args.order, args.uplink, seed, connected,
                      dict(args.device))
            rows.append(row)
            print(f"seed {seed}, connected_map {'on ' if connected else 'off'}: map in "
                  f"pieces {row['pieces_slots']} of {row['slots']} slots, the edge's lost "
                  f"share {row['edge_lost_share']:.1%}, the device's {row['device_lost_share']:.1%}"
                  f", {row['frames_tracked']} of {row['frames']} frames tracked, "
                  f"{row['uploads']} uploads, ATE {row['ate_m'] * 100:.2f} cm, "
                  f"{row['mended_slots']} slots mended, the check {row['check_ms_median']:.2f} ms "
                  f"a slot (median; longest {row['check_ms_max']:.1f}) ({row['seconds']:.0f} s)",
                  flush=True)
            if args.csv:
                append_csv_rows(args.csv, FIELDS, [row])


if __name__ == "__main__":
    main()
