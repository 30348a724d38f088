"""Pipeline benchmark: the device's ms per frame (tracking against the edge's map,
no image decoding) and the edge's ms per slot (plan + keyframe integration + GTSAM + eviction
+ checkpoint), with the device and edge cores driven in one process — exactly the work the
nodes do, without DDS and without the uplink's deliberate delay.

    python -m bench.pipeline [SEQUENCE] [--frames 600] [--policy adapt]

SEQUENCE defaults to ../shared/data/7scenes-1000. Targets: device ≤ 15 ms, edge ≤ 150 ms
(medians). ``plan`` is the policy's decision with its observation: the time the device waits
for the upload request beyond the summaries' trip (``--policy mpc:H=2`` for the planner).
"""

from __future__ import annotations

import argparse
import platform
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

from bench.gauge import cpu_gauge
from bench.in_process import serve_slot
from bench.paths import SEVEN_SCENES
from device_tracker.device_core import DeviceTrackerCore
from edge_mapper.edge_core import EdgeConfig, EdgeMapperCore
from twinslam.live.run_log import RunLog
from twinslam.live.tracking_quality import absolute_trajectory_error
from twinslam.policies.registry import make_policy
from twinslam.sequences.opening import open_sequence
from twinslam.slam.back_end.map_back_end import BackEndConfig
from twinslam.uplink.channels import parse_channel

DEFAULT = SEVEN_SCENES


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("sequence", nargs="?", default=str(DEFAULT),
                        help="RGB-D sequence folder (default: the bundled 7-Scenes sample)")
    parser.add_argument("--frames", type=int, default=600, help="frames to play")
    parser.add_argument("--policy", default="adapt", help="the edge's policy")
    parser.add_argument("--ba-window", type=int, default=BackEndConfig().ba_window,
                        help="newest keyframes the local bundle adjustment optimises")
    parser.add_argument("--ba-iterations", type=int, default=BackEndConfig().ba_iterations,
                        help="Gauss-Newton steps per adjustment")
    parser.add_argument("--ba-points", type=int, default=BackEndConfig().ba_points,
                        help="map points the adjustment takes at most, most observed first")
    args = parser.parse_args()
    cv2.setNumThreads(1)
    print(cpu_gauge(), "(before)")
    reader = open_sequence(args.sequence, end=args.frames)
    DeviceTrackerCore.warm_up(reader.intrinsics)
    device = DeviceTrackerCore(reader.intrinsics, 60)
    channel = parse_channel("markov:N=2", seed=0)
    device_ms, edge_ms = [], []
    record = RunLog()                      # poses and ground truth, for the ATE
    parts: dict[str, list[float]] = {"plan": [], "integrate": [], "finish": [], "optimise": [],
                                     "checkpoint": [], "uncertainty": []}
    with tempfile.TemporaryDirectory() as tmp:
        config = EdgeConfig(back_end=BackEndConfig(ba_window=args.ba_window,
                                                  ba_iterations=args.ba_iterations,
                                                  ba_points=args.ba_points))
        edge = EdgeMapperCore(make_policy(args.policy), reader.intrinsics, config,
                              Path(tmp) / "edge.npz")
        for frame in reader:
            t0 = time.perf_counter()
            result = device.track(frame.color, frame.depth, frame.stamp)
            device_ms.append((time.perf_counter() - t0) * 1000)
            if frame.pose is not None:
                record.poses[frame.index] = result.record.pose
                record.ground_truth[frame.index] = frame.pose
            if not result.slot_done:
                continue
            state, rate = channel.step()
            served = serve_slot(device, edge, rate, state)
            edge_ms.append(served.plan_ms + served.integrate_ms + served.finish_ms)
            for key, ms in (("plan", served.plan_ms), ("integrate", served.integrate_ms),
                            ("finish", served.finish_ms), *served.outcome.timings_ms.items()):
                parts.setdefault(key, []).append(ms)
    print(cpu_gauge(), "(after)")
    print(f"{platform.processor() or platform.machine()}, {reader.kind} {reader.path.name}, "
          f"{len(device_ms)} frames, policy {args.policy}, BA window {args.ba_window}, "
          f"{args.ba_iterations} iterations, at most {args.ba_points or 'all'} points")
    print(f"device ms/frame (tracking): median {np.median(device_ms):.1f}, p90 "
          f"{np.percentile(device_ms, 90):.1f}   target <= 15")
    print(f"edge ms/slot: median {np.median(edge_ms):.0f}, p90 {np.percentile(edge_ms, 90):.0f}"
          f" over {len(edge_ms)} slots   target <= 150")
    ate = absolute_trajectory_error(record.poses, record.ground_truth)
    print(f"device ATE (evo, SE(3)-aligned): {ate:.3f} m")
    print("  medians: " + ", ".join(f"{k} {np.median(v):.0f} ms" for k, v in parts.items())
          + " (finish = optimise + checkpoint + uncertainty + eviction)")


if __name__ == "__main__":
    main()
