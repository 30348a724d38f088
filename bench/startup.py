"""What starting the command line costs: the wall time of a fresh interpreter importing
``twinslam.cli.main`` (every ``twinslam`` command pays it, and so does every worker a sweep
spawns — a spawned worker re-imports the main module), and whether that import loads torch.

    .venv/bin/python -m bench.startup [--rounds 10] [--baseline COMMIT]

With ``--baseline`` the other commit's tree is timed in the same run, the two alternating
round by round (bench/baseline.py), so both see the same machine load.
"""

from __future__ import annotations

import argparse
import statistics
from pathlib import Path

from bench.baseline import alternately, run_in_tree

#: one fresh interpreter's import of the command line, timed from inside it after start-up
_DRIVER = """
import json, time
t0 = time.perf_counter()
import twinslam.cli.main
print(json.dumps({"seconds": time.perf_counter() - t0, "torch": "torch" in sys.modules}))
"""


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rounds", type=int, default=10,
                        help="fresh interpreters per tree (default %(default)s)")
    parser.add_argument("--baseline", metavar="COMMIT",
                        help="also time this commit's tree, alternating with this one")
    args = parser.parse_args()

    def measure(r: int, label: str, root: Path) -> dict[str, float | bool]:
        result: dict[str, float | bool] = run_in_tree(root, _DRIVER)
        print(f"round {r + 1} {label}: {float(result['seconds']):.2f} s", flush=True)
        return result

    trees = alternately(args.baseline, args.rounds, measure)
    for label, runs in trees.items():
        name = args.baseline if label == "baseline" else "this tree"
        seconds = [float(r["seconds"]) for r in runs]
        print(f"{name:<12} import twinslam.cli.main: median {statistics.median(seconds):.2f} s "
              f"(min {min(seconds):.2f}, max {max(seconds):.2f}, {len(seconds)} runs); "
              f"loads torch: {'yes' if runs[0]['torch'] else 'no'}")


if __name__ == "__main__":
    main()
