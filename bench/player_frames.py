"""What the sequence player spends on a frame before it publishes it: decoding the colour and
depth images, registering the depth to the colour camera (7-Scenes), and the four messages —
CPU milliseconds a frame, in a fresh interpreter per round.

    .venv/bin/python -m bench.player_frames [SEQUENCE] [--frames 200] [--rounds 4]
                                            [--baseline COMMIT] [--frame-cache DIR]

SEQUENCE defaults to the bundled 7-Scenes sample, read as the player reads it
(``colour_intrinsics: auto``). On a 2-core machine the player shares the cores with the device
it feeds, so its CPU is taken from the device's. With ``--baseline`` the other commit's tree
is measured in the same run, the two alternating round by round (bench/baseline.py); each
round's first frame (the numba kernels loading, compiled in a fresh baseline tree) is left out.
With ``--frame-cache`` this tree reads through the decoded-frame cache in DIR
(:mod:`twinslam.sequences.decoded_frames`): its first round decodes and writes the frames, the
later ones read them back (a commit without the cache decodes every round).
"""

from __future__ import annotations

import argparse
import os
import statistics

from bench.baseline import add_baseline_options, drive_alternately
from bench.gauge import cpu_gauge
from bench.paths import SEVEN_SCENES

DEFAULT = SEVEN_SCENES

#: one round in a tree: argv = [sequence, frames, tree]; prints the CPU ms a frame
_DRIVER = """
import json, time
from twinslam.sequence_player.messages import (camera_info_message, color_message,
                                               depth_message, pose_message)
import inspect
from twinslam.sequences.opening import open_sequence

sequence, frames = sys.argv[1], int(sys.argv[2])
# the cache TWINSLAM_FRAME_CACHE names, as the player opens its sequence (a tree from before
# the cache has no such argument and decodes every frame)
cached = {}
if "frame_cache" in inspect.signature(open_sequence).parameters:
    from twinslam.sequences.decoded_frames import DecodedFrameCache
    cached["frame_cache"] = DecodedFrameCache.from_environment()
reader = iter(open_sequence(sequence, end=frames + 1, colour_intrinsics="auto", **cached))
next(reader)                                   # the kernels load: left out
read_s, messages_s, n = 0.0, 0.0, 0
t0 = time.process_time()
for frame in reader:
    t1 = time.process_time()
    color_message(frame, frame.stamp, "camera")
    depth_message(frame, frame.stamp, "camera")
    camera_info_message(frame, frame.stamp, "camera")
    if frame.pose is not None:
        pose_message(frame.pose, frame.stamp, "world")
    t2 = time.process_time()
    read_s += t1 - t0
    messages_s += t2 - t1
    n += 1
    t0 = time.process_time()
print(json.dumps({"read_ms": read_s / n * 1000, "messages_ms": messages_s / n * 1000,
                  "frames": n}))
"""


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("sequence", nargs="?", default=str(DEFAULT),
                        help="RGB-D sequence (default: the bundled 7-Scenes sample)")
    parser.add_argument("--frames", type=int, default=200,
                        help="frames a round times, after its first (default %(default)s)")
    parser.add_argument("--frame-cache", metavar="DIR",
                        help="read through the decoded-frame cache in DIR (its first round "
                             "fills it; default: no cache)")
    add_baseline_options(parser, 4, "fresh interpreters per tree")
    args = parser.parse_args()
    if args.frames < 1 or args.rounds < 1:
        parser.error("--frames and --rounds must be at least 1")
    os.environ.pop("TWINSLAM_FRAME_CACHE", None)
    if args.frame_cache:
        os.environ["TWINSLAM_FRAME_CACHE"] = args.frame_cache
    print(cpu_gauge(), "(before)", flush=True)

    trees = drive_alternately(
        args.baseline, args.rounds, _DRIVER, [args.sequence, str(args.frames)],
        lambda result: f"read {result['read_ms']:.1f} ms, messages {result['messages_ms']:.1f} "
                       f"ms a frame ({int(result['frames'])} frames)")
    for name, runs in trees.items():
        read = [r["read_ms"] for r in runs]
        messages = [r["messages_ms"] for r in runs]
        print(f"{name:<12} CPU a frame: read (decode + registration) median "
              f"{statistics.median(read):.1f} ms (min {min(read):.1f}, max {max(read):.1f}), "
              f"messages {statistics.median(messages):.1f} ms; {len(runs)} rounds")
    print(cpu_gauge(), "(after)")


if __name__ == "__main__":
    main()
