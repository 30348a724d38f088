"""``twinslam extract``: a covisibility dataset from an RGB-D sequence (the device's front end)."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from pathlib import Path

import numpy as np

from twinslam.cli.console import Subparsers, error
from twinslam.covisibility.dataset import save_covisibility
from twinslam.sequences.frame import SequenceError
from twinslam.sequences.opening import open_sequence
from twinslam.simulator.extraction import extract_covisibility
from twinslam.slam.front_end.tracking import TrackingConfig


def run(args: argparse.Namespace) -> int:

    out = Path(args.output)
    if not out.parent.is_dir():
        return error(f"output folder {out.parent} does not exist")
    try:
        reader = open_sequence(args.sequence, args.start, args.end)
    except SequenceError as exc:
        return error(exc)
    print(f"extracting {len(reader)} frames of {reader.kind} sequence {reader.path}", flush=True)

    tty = sys.stdout.isatty()

    def counter(what: str) -> Callable[[int, int], None]:
        """A progress line for one pass over the frames: redrawn on a terminal, every 100th
        frame in a log."""
        def progress(done: int, total: int) -> None:
            if tty and (done == total or done % 10 == 0):
                print(f"\r  {what}{done}/{total} frames", end="\n" if done == total else "",
                      flush=True)
            elif not tty and (done == total or done % 100 == 0):
                print(f"  {what}{done}/{total} frames", flush=True)
        return progress

    try:
        dataset, _, report = extract_covisibility(
            reader, TrackingConfig(n_features=args.features), counter(""), guided=args.guided,
            guided_progress=counter("guided over the whole map: "))
    except ValueError as exc:
        return error(exc)
    save_covisibility(out, dataset)
    sizes = np.diff(dataset.point_offsets)
    print(f"wrote {out}: {report.frames} frames, {report.map_points} map points, "
          f"{sizes.mean():.0f} observed per frame, {report.keyframes} keyframes, "
          f"{report.untracked} untracked, {len(report.skipped)} skipped files; "
          f"front end {np.median(report.frontend_ms):.1f} ms/frame median, "
          f"{report.seconds:.1f} s in all")
    return 0


def register(sub: Subparsers) -> None:
    extract = sub.add_parser("extract", help="covisibility dataset from an RGB-D sequence",
                             description="Runs the device's ORB front end and tracking over a "
                             "sequence and stores which map points every frame observes (the "
                             "simulator's and the trainer's --covis).")
    extract.add_argument("sequence", help="a SUN3D, 7-Scenes or TUM RGB-D folder, a recorded "
                         "bag, or synthetic[:frames] (the room) / synthetic-corridor[:frames]")
    extract.add_argument("-o", "--output", required=True, help="covisibility .npz to write")
    extract.add_argument("--start", type=int, default=0, help="index of the first frame read")
    extract.add_argument("--end", type=int, default=-1,
                         help="index of the first frame not read (-1: to the end)")
    extract.add_argument("--features", type=int, default=1000, help="ORB features per frame")
    extract.add_argument("--guided", action=argparse.BooleanOptionalAction, default=True,
                         help="match every frame again against the whole finished map, as "
                         "ORB-SLAM's local map search does (two fifths of the time on the "
                         "7-Scenes sample): a frame's points then include the old keyframes' "
                         "it sees, which tracking alone underrates; --no-guided keeps the "
                         "tracked observations only, for a quick look or the front end's "
                         "poses (default: guided)")
    extract.set_defaults(func=run)
