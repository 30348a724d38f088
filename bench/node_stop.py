"""How long each node's process takes to end once asked: SIGTERM to exit, measured from the
asking side — what ``ros2 launch`` waits for (5 s before SIGTERM follows SIGINT, 5 more before
SIGKILL) and what a test's stop grants.

    .venv/bin/python -m bench.node_stop [--rounds 5] [--baseline COMMIT]

Each node runs as ``python -m MODULE`` on a private loopback domain, idle (started, not fed:
its stop is what is timed, not the work it was doing), and is stopped once its log says it
is up. With ``--baseline`` the other commit's tree is timed in the same run, the two
alternating round by round (bench/baseline.py).
"""

from __future__ import annotations

import argparse
import json
import statistics

from bench.baseline import add_baseline_options, drive_alternately

#: each node's module, the arguments it is started with and the line that says it is up
NODES = {
    "udt_node": ("udt_node.node", [], "listening on"),
    "edge_mapper": ("edge_mapper.node", [], "listening on"),
    "device_tracker": ("device_tracker.node", [], "waiting for"),
    "sequence_player": ("twinslam.sequence_player.node",
                        ["--ros-args", "-p", "wait_for_subscribers:=1"], "waiting for"),
}

#: one round in a tree: every node started, stopped with SIGTERM once up, its exit timed
_DRIVER = """
import json, signal, time
from twinslam.hosts.loopback import LoopbackDomain
nodes = json.loads(sys.argv[1])
out = {}
with LoopbackDomain() as domain:
    for name, (module, extra, up) in nodes.items():
        proc = domain.spawn(["-m", module, *extra])
        if not domain.wait_for_log(proc, up, 120):
            raise SystemExit(f"{name} did not come up: {domain.log(proc)[-1500:]}")
        time.sleep(0.5)
        began = time.perf_counter()
        proc.send_signal(signal.SIGTERM)
        code = proc.wait(timeout=60)
        out[name] = {"seconds": time.perf_counter() - began, "code": code}
print(json.dumps(out))
"""


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    add_baseline_options(parser, 5, "rounds per tree, every node once a round")
    args = parser.parse_args()
    trees = drive_alternately(
        args.baseline, args.rounds, _DRIVER, [json.dumps(NODES)],
        lambda result: ", ".join(f"{name} {float(r['seconds']):.2f} s (exit {r['code']})"
                                 for name, r in result.items()))
    for tree, runs in trees.items():
        for name in NODES:
            seconds = [float(run[name]["seconds"]) for run in runs]
            codes = sorted({int(run[name]["code"]) for run in runs})
            print(f"{tree:<12} {name:<16} SIGTERM to exit: median "
                  f"{statistics.median(seconds):.2f} s (min {min(seconds):.2f}, max "
                  f"{max(seconds):.2f}, {len(seconds)} runs), "
                  f"exit codes {codes}")


if __name__ == "__main__":
    main()
