"""A node's log line, side by side: rclpy's ``logger.info`` (which names the call site by
walking the stack with ``inspect`` on every line) against
:class:`twinslam.node_runtime.site_logging.SiteLogger` (the same rcutils call, the call site
read from the caller's frame). Both write with rclpy's output handlers as a node has them
(the console — sent to /dev/null here —, the log file under ``ROS_LOG_DIR``, ``/rosout`` on a
private loopback domain), from a call stack as deep as an edge's slot callback, in alternated
rounds.

    python -m bench.site_logging [--lines 2000] [--rounds 5] [--depth 25]
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import sys
import tempfile
import time
from collections.abc import Callable

from twinslam.hosts.loopback import LoopbackDomain
from twinslam.node_runtime.session import RosSession
from twinslam.node_runtime.site_logging import SiteLogger


def _at_depth(depth: int, call: Callable[[], None]) -> None:
    if depth <= 0:
        call()
    else:
        _at_depth(depth - 1, call)


def _per_line_us(write: Callable[[str], None], lines: int, depth: int) -> float:
    def burst() -> None:
        for i in range(lines):
            write(f"[ar{i % 50}] slot {i}: +1 keyframes")
    start = time.perf_counter()
    _at_depth(depth, burst)
    return (time.perf_counter() - start) / lines * 1e6


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0],
        formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    parser.add_argument("--lines", type=int, default=2000, help="lines a round and a way")
    parser.add_argument("--rounds", type=int, default=5,
                        help="rounds, each writing both ways one after the other")
    parser.add_argument("--depth", type=int, default=25,
                        help="frames between the spin and the line (an edge's slot callback "
                             "writes from about 25)")
    args = parser.parse_args(argv)
    sink = os.open(os.devnull, os.O_WRONLY)
    saved = os.dup(2)
    times: dict[str, list[float]] = {"rclpy's logger.info": [], "SiteLogger.info": []}
    with tempfile.TemporaryDirectory(prefix="site-logging-") as logs, \
            LoopbackDomain() as domain:
        os.environ.setdefault("ROS_LOG_DIR", logs)      # the lines' files, gone after
        domain.activate()
        with RosSession("site_logging_bench") as session:
            logger = session.node.get_logger()
            ways: dict[str, Callable[[str], None]] = {
                "rclpy's logger.info": logger.info, "SiteLogger.info": SiteLogger(logger).info}
            os.dup2(sink, 2)                # rcutils' console lines, not the terminal
            try:
                for _ in range(args.rounds):
                    for name, write in ways.items():
                        times[name].append(_per_line_us(write, args.lines, args.depth))
            finally:
                os.dup2(saved, 2)
                os.close(saved)
                os.close(sink)
    print(f"machine: {platform.machine()}, {os.cpu_count()} cores, python "
          f"{platform.python_version()}; {args.lines} lines a round, {args.rounds} rounds, "
          f"{args.depth} frames deep; console to /dev/null, log file and /rosout on")
    for name, values in times.items():
        print(f"{name:>22}: median {statistics.median(values):7.1f} µs a line "
              f"(rounds {', '.join(f'{v:.1f}' for v in values)})")
    ratio = statistics.median(times["rclpy's logger.info"]) / \
        statistics.median(times["SiteLogger.info"])
    print(f"{'':>22}  rclpy's takes {ratio:.0f}× the site logger's time a line")
    return 0


if __name__ == "__main__":
    sys.exit(main())
