"""What starting the command line costs: the wall time of a fresh interpreter importing
``twinslam.cli.main`` (every worker a sweep spawns re-imports the main module) and building
the parser of one command (every ``twinslam COMMAND`` pays both before it runs), and whether
that loads torch or rclpy.

    .venv/bin/python -m bench.startup [--command sim] [--rounds 10] [--baseline COMMIT]

With ``--baseline`` the other commit's tree is timed in the same run, the two alternating
round by round (bench/baseline.py), so both see the same machine load.
"""

from __future__ import annotations

import argparse
import statistics

from bench.baseline import add_baseline_options, drive_alternately

#: one fresh interpreter's import of the command line and its parser for the command in
#: argv[1], timed from inside it after start-up (a tree older than the parser of one command
#: builds every command's, as its ``twinslam COMMAND`` did)
_DRIVER = """
import json, time
t0, c0 = time.perf_counter(), time.process_time()
import twinslam.cli.main
imported = time.perf_counter() - t0
try:
    twinslam.cli.main.build_parser(sys.argv[1])
except TypeError:
    twinslam.cli.main.build_parser()
print(json.dumps({"import_s": imported, "seconds": time.perf_counter() - t0,
                  "cpu_s": time.process_time() - c0, "torch": "torch" in sys.modules,
                  "rclpy": "rclpy" in sys.modules}))
"""


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--command", default="sim",
                        help="the command whose parser is built (default %(default)s)")
    add_baseline_options(parser, 10, "fresh interpreters per tree")
    args = parser.parse_args()

    trees = drive_alternately(args.baseline, args.rounds, _DRIVER, [args.command],
                              lambda result: f"{float(result['seconds']):.2f} s "
                                             f"({float(result['cpu_s']):.2f} s of CPU)")
    for name, runs in trees.items():
        seconds = [float(r["seconds"]) for r in runs]
        cpu = [float(r["cpu_s"]) for r in runs]
        imported = [float(r["import_s"]) for r in runs]
        print(f"{name:<12} twinslam {args.command}'s start (import and parser): median "
              f"{statistics.median(seconds):.2f} s (min {min(seconds):.2f}, max "
              f"{max(seconds):.2f}, {len(seconds)} runs), {statistics.median(cpu):.2f} s of "
              f"CPU; the import alone {statistics.median(imported):.2f} s; loads torch: "
              f"{'yes' if runs[0]['torch'] else 'no'}, rclpy: "
              f"{'yes' if runs[0]['rclpy'] else 'no'}")


if __name__ == "__main__":
    main()
