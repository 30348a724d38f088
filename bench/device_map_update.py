"""How long the device takes to swap in each map update the edge sends: the tracking thread's
pause between two frames while it renames the tracks the edge resolved, finds the update's
points among its own and builds the map it tracks on next (``DeviceTrackerCore.
apply_map_update``) — on a phone, time the next camera frame waits for.

    .venv/bin/python -m bench.device_map_update [SEQUENCE] [--order forward_backward]
                                                [--rounds 2] [--baseline COMMIT]

The device and the edge in one process over the walk (``bench.edge_work``'s slots: the
default device and edge, every message (de)serialised as on the wire), every update the
device applies timed. With ``--baseline`` the other commit's tree is timed in the same run,
the two alternating round by round (bench/baseline.py).
"""

from __future__ import annotations

import argparse
import statistics

from bench.baseline import add_baseline_options, drive_alternately
from bench.paths import SEVEN_SCENES
from twinslam.cli.console import HelpFormatter

#: one round in a tree: bench.edge_work's walk with the device's map updates timed
_DRIVER = """
import contextlib, io, json, time
from device_tracker.device_core import DeviceTrackerCore
from bench import edge_work
times = []
apply = DeviceTrackerCore.apply_map_update
def timed(self, update, slot):
    began = time.perf_counter()
    try:
        return apply(self, update, slot)
    finally:
        times.append((time.perf_counter() - began) * 1e3)
DeviceTrackerCore.apply_map_update = timed
sys.argv = ["edge_work", sys.argv[1], "--order", sys.argv[2]]
with contextlib.redirect_stdout(io.StringIO()):
    edge_work.main()
print(json.dumps(times))
"""


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0],
                                     epilog=__doc__.split("\n", 2)[2],
                                     formatter_class=HelpFormatter)
    parser.add_argument("sequence", nargs="?", default=str(SEVEN_SCENES),
                        help="the walk (default: the 7-Scenes frames)")
    parser.add_argument("--order", default="forward_backward",
                        choices=("forward", "forward_backward"),
                        help="play order (forward_backward: every place twice)")
    add_baseline_options(parser, 2, "rounds per tree, the whole walk once a round")
    args = parser.parse_args()

    def describe(times: list[float]) -> str:
        return (f"{len(times)} updates, median {statistics.median(times):.1f} ms, "
                f"total {sum(times):.0f} ms")

    trees = drive_alternately(args.baseline, args.rounds, _DRIVER,
                              [str(args.sequence), args.order], describe)
    for tree, runs in trees.items():
        every = sorted(t for run in runs for t in run)
        p95 = every[min(len(every) - 1, int(0.95 * len(every)))]
        print(f"{tree:<12} the device's map update: median {statistics.median(every):.1f} ms, "
              f"p95 {p95:.1f} ms over {len(every)} updates in {len(runs)} walks; a walk's "
              f"total {statistics.median(sum(run) for run in runs):.0f} ms (median)")


if __name__ == "__main__":
    main()
