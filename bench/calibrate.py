"""What `twinslam calibrate` costs on committed sweeps: reading their frames (one row per
next-slot frame of every run), fitting and levelling the lost-frame threshold, the tables and
the figure — in a fresh interpreter, CPU seconds from inside it.

    .venv/bin/python -m bench.calibrate [--rounds 3] [--baseline COMMIT] [FOLDER ...]

Default folders: the default device's 300- and 1000-frame Table I sweeps
(docs/figures/default-device/), as the results pages calibrate them. With ``--baseline`` the
other commit's tree runs in the same rounds, alternating (bench/baseline.py).
"""

from __future__ import annotations

import argparse
import statistics
from pathlib import Path

from bench.baseline import add_baseline_options, drive_alternately
from bench.paths import REPO

DEFAULT_FOLDERS = [REPO / "docs" / "figures" / "default-device" / name
                   for name in ("table-i-300", "table-i-1000")]

#: `twinslam calibrate FOLDER... --out PNG` in a fresh interpreter, timed from inside it
_DRIVER = """
import contextlib, io, json, sys, tempfile, time
from twinslam.cli.main import main
folders = sys.argv[1:-1]
with tempfile.TemporaryDirectory() as tmp:
    c0, t0 = time.process_time(), time.perf_counter()
    with contextlib.redirect_stdout(io.StringIO()):
        code = main(["calibrate", *folders, "--out", tmp + "/calibration.png"])
    print(json.dumps({"code": code, "cpu_s": time.process_time() - c0,
                      "seconds": time.perf_counter() - t0}))
"""


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("folders", nargs="*", type=Path, default=DEFAULT_FOLDERS,
                        help="evaluation folders with calibration_frames.csv[.gz] (default: "
                             "the default device's Table I sweeps)")
    add_baseline_options(parser, 3, "fresh interpreters per tree")
    args = parser.parse_args()
    folders = [str(folder.resolve()) for folder in args.folders]
    trees = drive_alternately(args.baseline, args.rounds, _DRIVER, folders, lambda result: (
        f"{result['cpu_s']:.2f} s of CPU, {result['seconds']:.2f} s (exit {result['code']})"))
    for name, runs in trees.items():
        if any(run["code"] != 0 for run in runs):
            raise SystemExit(f"twinslam calibrate failed in {name}")
        cpu = [run["cpu_s"] for run in runs]
        print(f"{name:<12} calibrate: median {statistics.median(cpu):.2f} s of CPU "
              f"(min {min(cpu):.2f}, max {max(cpu):.2f}, {len(cpu)} runs)")

if __name__ == "__main__":
    main()
