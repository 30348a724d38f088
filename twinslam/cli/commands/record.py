"""``twinslam record``: a sequence's camera topics written as a rosbag2 (MCAP)."""

from __future__ import annotations

import argparse

from twinslam.cli.console import Subparsers, error
from twinslam.sequence_player.sequence_bag import record_bag
from twinslam.sequences.frame import SequenceError
from twinslam.sequences.opening import open_sequence


def run(args: argparse.Namespace) -> int:

    try:
        reader = open_sequence(args.sequence, args.start, args.end)
        print(f"recording {len(reader)} frames of {reader.kind} sequence {reader.path} to "
              f"{args.output} (rosbag2, MCAP)", flush=True)
        written = record_bag(reader, args.output)
    except SequenceError as exc:
        return error(exc)
    print(f"wrote {written} frames, {len(reader.skipped)} skipped"
          f"{': ' + ', '.join(reader.skipped) if reader.skipped else ''}")
    return 0


def register(sub: Subparsers) -> None:
    record = sub.add_parser("record", help="a sequence's camera topics as a rosbag2 (MCAP)")
    record.add_argument("sequence", help="a SUN3D, 7-Scenes or TUM RGB-D folder")
    record.add_argument("-o", "--output", required=True, help="rosbag2 folder to create")
    record.add_argument("--start", type=int, default=0, help="index of the first frame recorded")
    record.add_argument("--end", type=int, default=-1,
                        help="index of the first frame not recorded (-1: to the end)")
    record.set_defaults(func=run)
