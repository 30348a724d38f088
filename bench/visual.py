"""What the edge's viewer topics cost a slot: building ``edge/map_points`` (PointCloud2),
``edge/keyframes`` (PoseArray) and ``edge/decisions`` (MarkerArray) and serialising them as
rclpy would put them on the wire, for a full map (V_max keyframes) of growing point counts;
and what one ``edge/keyframe_trajectory`` (nav_msgs/Path of the map's and a full archive's
keyframes) costs, sent every ``trajectory_every`` slots and after loops, not every slot.

    python -m bench.visual [--keyframes 45] [--points 5000,20000,60000] [--archive 500]
                           [--repeats 20]
"""

from __future__ import annotations

import argparse
import functools
import platform
import statistics
import time
from collections.abc import Callable
from typing import Any

import numpy as np
from rclpy.serialization import serialize_message

from bench.gauge import cpu_gauge
from edge_mapper.visual_messages import (
    decisions_message,
    keyframe_trajectory_message,
    keyframes_message,
    map_points_message,
)
from twinslam.slam.back_end.keyframe_map import KeyFrameMap


def full_map(keyframes: int, points: int, seed: int = 0) -> KeyFrameMap:
    """``keyframes`` keyframes, each observing a random quarter of ``points`` points."""
    rng = np.random.default_rng(seed)
    m = KeyFrameMap()
    for k in range(keyframes):
        pose = np.eye(4)
        pose[:3, 3] = rng.normal(size=3)
        m.add_keyframe(k, pose)
    descriptor = np.zeros(32, np.uint8)
    for _ in range(points):
        pid = m.add_point(rng.normal(size=3), descriptor)
        for k in rng.choice(keyframes, size=max(1, keyframes // 4), replace=False):
            m.observe(int(k), pid, (320.0, 240.0), 2.0)
    return m


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--keyframes", type=int, default=45, help="keyframes in the map")
    parser.add_argument("--points", default="5000,20000,60000",
                        help="comma-separated map point counts")
    parser.add_argument("--archive", type=int, default=500,
                        help="archived keyframes in the keyframe trajectory (the edge's "
                             "archive_keyframes)")
    parser.add_argument("--repeats", type=int, default=20, help="timed builds per size")
    args = parser.parse_args()
    print(f"machine: {platform.node()} {platform.machine()}, python "
          f"{platform.python_version()}; {cpu_gauge()}")
    print(f"{'points':>8} {'cloud ms':>9} {'poses ms':>9} {'markers ms':>11} {'total ms':>9} "
          f"{'cloud MB':>9}")
    for n in (int(x) for x in args.points.split(",")):
        m = full_map(args.keyframes, n)
        before = {k: kf.pose for k, kf in m.keyframes.items()}
        times: dict[str, list[float]] = {"cloud": [], "poses": [], "marks": []}
        size = 0
        builds: tuple[tuple[str, Callable[[], Any]], ...] = (
            ("cloud", functools.partial(map_points_message, m, 1.0)),
            ("poses", functools.partial(keyframes_message, m, 1.0)),
            ("marks", functools.partial(decisions_message, m, [0, 1], [], before, 1.0)))
        for _ in range(args.repeats):
            for key, build in builds:
                t0 = time.perf_counter()
                data = serialize_message(build())
                times[key].append((time.perf_counter() - t0) * 1000)
                size = len(data) if key == "cloud" else size
        med = {k: statistics.median(v) for k, v in times.items()}
        print(f"{n:>8} {med['cloud']:>9.2f} {med['poses']:>9.2f} {med['marks']:>11.2f} "
              f"{sum(med.values()):>9.2f} {size / 1e6:>9.2f}", flush=True)
    count = args.keyframes + args.archive
    trajectory = [(0.1 * k, np.eye(4)) for k in range(count)]
    spent = []
    for _ in range(args.repeats):
        t0 = time.perf_counter()
        serialize_message(keyframe_trajectory_message(trajectory, 1.0))
        spent.append((time.perf_counter() - t0) * 1000)
    print(f"keyframe trajectory of {count} keyframes: {statistics.median(spent):.1f} ms a "
          "message", flush=True)


if __name__ == "__main__":
    main()
