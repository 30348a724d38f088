"""What the edge does for one device-slot, step by step: where the ~90 ms a device-slot of
``bench.edge_scaling`` go — reading the device's messages, the policy's plan, integrating
keyframes, the slot's end (archive, bundle adjustment, checkpoint, υ, the loop closer's
work), and writing the map update, the statistics and the viewer's messages.

    python -m bench.edge_work [SEQUENCE] [--frames 1000] [--order forward] [--seed 0] [--uplink lte]
                              [--checkpoints slot] [--csv FILE]

One default device and edge over the sequence in one process (the device's tracking is not
counted), every message the edge node reads or writes made and (de)serialised as rclpy does on
the wire — DDS's own transport and the executor are left out (``bench.dds``). The loop closer
runs in the caller: its work, which the node does on a thread of the same process, counts in the
slot it was started by. The map is checkpointed every slot, on the slot's path as the node does
by default (``--checkpoints background``: written on a thread of its own, as
``checkpoint_in_background:=true``; the step then holds only the gathering). Prints each step's
median, p95 and share of the edge's time over the walk's slots; ``--csv`` writes every slot's
steps.
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import platform
import tempfile
import time
from collections import defaultdict
from pathlib import Path

import numpy as np
from rclpy.serialization import deserialize_message, serialize_message
from twinslam_msgs.msg import FrameSummaries, Keyframe

from bench.in_process import ServedSlot, open_walk, repeatable_edge, run_as_the_edge_node
from bench.paths import SEVEN_SCENES
from device_tracker.device_core import DeviceTrackerCore
from device_tracker.messages import frame_summaries_message, keyframe_message, read_map_update
from edge_mapper.checkpoint_writer import CheckpointWriter
from edge_mapper.edge_core import EdgeMapperCore
from edge_mapper.messages import (
    map_stats_message,
    map_update_message,
    read_frame_summaries,
    read_keyframe,
    upload_request_message,
)
from edge_mapper.visual_messages import decisions_message, keyframes_message, map_points_message
from twinslam.cli.console import HelpFormatter

SEVEN = SEVEN_SCENES

#: the steps, in the order the edge takes them
STEPS = ("summaries in", "plan", "request out", "keyframes in", "integrate", "archive",
         "bundle adjustment", "checkpoint", "uncertainty", "loop closer", "slot end, rest",
         "map update out", "stats out", "viewer out")


class StepClock:
    """Each served slot's milliseconds per step."""

    def __init__(self) -> None:
        self.slots: list[dict[str, float]] = []
        self.integrated = 0               #: keyframes the edge integrated over the walk

    def serve(self, device: DeviceTrackerCore, edge: EdgeMapperCore, rate_mbps: float,
              rate_state: int, hold: bool) -> ServedSlot:
        """One slot as the edge node serves it (``DeviceLink``), every step timed."""
        ms: dict[str, float] = defaultdict(float)
        frames = device.take_slot()
        slot = frames[-1].slot
        wire = serialize_message(frame_summaries_message(slot, rate_mbps, rate_state,
                                                         device.map_version, frames,
                                                         time.time()))
        t = time.perf_counter()
        msg = deserialize_message(wire, FrameSummaries)
        summaries = read_frame_summaries(msg)
        t = _lap(ms, "summaries in", t)
        plan = edge.plan(slot, summaries, rate_mbps, rate_state)
        t = _lap(ms, "plan", t)
        serialize_message(upload_request_message(slot, "lff", rate_mbps, plan.action,
                                                 time.time()))
        t = _lap(ms, "request out", t)
        for frame_id in plan.action.upload:
            payload = device.upload(frame_id)
            if payload is None:
                continue
            sent = serialize_message(keyframe_message(dataclasses.replace(payload, slot=slot)))
            t = time.perf_counter()
            data = read_keyframe(deserialize_message(sent, Keyframe))
            t = _lap(ms, "keyframes in", t)
            edge.add_keyframe(data)
            t = _lap(ms, "integrate", t)
        t = time.perf_counter()
        outcome = edge.finish_slot(slot)
        finish_ms = (time.perf_counter() - t) * 1e3
        steps = outcome.timings_ms
        for name, key in (("archive", "archive"), ("bundle adjustment", "optimise"),
                          ("checkpoint", "checkpoint"), ("uncertainty", "uncertainty"),
                          ("loop closer", "loop")):
            ms[name] += steps.get(key, 0.0)
        ms["slot end, rest"] += max(finish_ms - sum(steps.values()), 0.0)
        t = time.perf_counter()
        update = map_update_message(edge.map, slot, outcome.version, time.time(),
                                    tracks=outcome.tracks, frame_correction=edge.frame_correction)
        serialize_message(update)
        t = _lap(ms, "map update out", t)
        serialize_message(map_stats_message(slot, "lff", edge.map, outcome.map_uncertainty,
                                            None, len(outcome.integrated), 0.0, 0.0,
                                            time.time()))
        t = _lap(ms, "stats out", t)
        now = time.time()
        for view in (map_points_message(edge.map, now), keyframes_message(edge.map, now),
                     decisions_message(edge.map, outcome.integrated, outcome.evicted, {}, now,
                                       "map", outcome.restored)):
            serialize_message(view)
        _lap(ms, "viewer out", t)
        self.slots.append(dict(ms))
        self.integrated += len(outcome.integrated)
        total = sum(ms.values())
        snapshot = read_map_update(update)
        if not hold:
            device.apply_map_update(snapshot, slot)
        return ServedSlot(outcome, ms["plan"], ms["integrate"], total, snapshot if hold else None)


def _lap(ms: dict[str, float], step: str, since: float) -> float:
    """Add the time since ``since`` to ``step``; now."""
    now = time.perf_counter()
    ms[step] += (now - since) * 1e3
    return now


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0],
                                     epilog=__doc__.split("\n", 2)[2],
                                     formatter_class=HelpFormatter)
    parser.add_argument("sequence", nargs="?", default=str(SEVEN),
                        help="the walk (default: the 7-Scenes frames)")
    parser.add_argument("--frames", type=int, default=1000, help="frames to play")
    parser.add_argument("--order", default="forward", choices=("forward", "forward_backward"),
                        help="play order: forward_backward visits every place twice, and the "
                        "edge restores archived keyframes on the way back")
    parser.add_argument("--seed", type=int, default=0, help="the uplink's seed")
    parser.add_argument("--uplink", default="lte", help="uplink family (table1, lte, mmwave, "
                        "constrained)")
    parser.add_argument("--checkpoints", default="slot", choices=("slot", "background"),
                        help="where the checkpoint files are written: on the node's writer "
                        "thread (checkpoint_in_background:=true) or on the slot's path (the "
                        "node's default)")
    parser.add_argument("--own-coverage-after", type=int, default=0, metavar="N",
                        help="the device's own keyframes of an earlier visit (restored, or "
                             "uploaded N slots before or more) cover its views: the frames "
                             "beside them are not uploaded (the edge's "
                             "own_coverage_after_slots; 0: the node's default, never)")
    parser.add_argument("--csv", type=Path, help="write every slot's steps (ms) here")
    args = parser.parse_args()
    run_as_the_edge_node()
    config = repeatable_edge(own_coverage_after_slots=args.own_coverage_after)
    clock = StepClock()
    with tempfile.TemporaryDirectory() as tmp:
        walk = open_walk("edge", args.sequence, args.frames, args.order, args.seed, args.uplink,
                         config, 8, Path(tmp))
        walk.serve = clock.serve
        writer = CheckpointWriter() if args.checkpoints == "background" else None
        walk.edge.writer = writer
        started = time.perf_counter()
        while walk.step() is not None:
            pass
        walk.edge.flush_checkpoint()
        archived = len(walk.edge.archive)
        walk.edge.close()
        if writer is not None:
            writer.close()
        walk_s = time.perf_counter() - started
    slots = clock.slots[1:]                        # the first slot's map is one keyframe
    totals = np.array([sum(s.values()) for s in slots])
    print(f"machine: {platform.machine()}, python {platform.python_version()}; "
          f"{args.sequence} ({args.frames} frames, {args.order}), the default edge"
          + (f" with its own keyframes covering views after {args.own_coverage_after} slots"
             if args.own_coverage_after else "")
          + f", {len(slots)} slots, checkpoints written "
          f"{'on a thread of their own' if writer else 'on the slot path'}; "
          f"the walk (tracking and reading frames included) {walk_s:.1f} s; "
          f"{clock.integrated} keyframes integrated, {archived} archived at the end")
    print(f"{'step':>18} {'median ms':>10} {'p95 ms':>8} {'share':>6}")
    for step in STEPS:
        values = np.array([s.get(step, 0.0) for s in slots])
        print(f"{step:>18} {np.median(values):10.1f} {np.percentile(values, 95):8.1f} "
              f"{values.sum() / totals.sum():6.1%}")
    print(f"{'a device-slot':>18} {np.median(totals):10.1f} {np.percentile(totals, 95):8.1f} "
          f"{1:6.0%}")
    if args.csv:
        with args.csv.open("w", newline="") as f:
            rows = csv.DictWriter(f, fieldnames=["slot", *STEPS])
            rows.writeheader()
            for i, s in enumerate(slots, start=1):
                rows.writerow({"slot": i, **{k: f"{s.get(k, 0.0):.3f}" for k in STEPS}})


if __name__ == "__main__":
    main()
