"""Front-end benchmark: ms per 640×480 frame for ORB extraction + projection
matching + PnP + map-point bookkeeping, on one core, and the extraction time of a sequence.

    python -m bench.frontend [SEQUENCE] [--frames 1000] [--colour-intrinsics auto|FILE]

SEQUENCE defaults to ../shared/data/7scenes-1000. Image decoding is timed separately: it is
the reader's cost, not the front end's. ``--colour-intrinsics`` reads the sequence as the
player does with its ``colour_intrinsics`` parameter (``auto``, its default: a 7-Scenes
scene's depth registered to its colour camera), the registration timed with the decoding.
"""

from __future__ import annotations

import argparse
import platform
import time

import cv2
import numpy as np

from bench.gauge import cpu_gauge
from bench.paths import SEVEN_SCENES
from twinslam.sequences.opening import open_sequence
from twinslam.slam.front_end.tracking import Tracking

DEFAULT = SEVEN_SCENES


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("sequence", nargs="?", default=str(DEFAULT),
                        help="RGB-D sequence folder (default: the bundled 7-Scenes sample)")
    parser.add_argument("--frames", type=int, default=1000, help="frames to time")
    parser.add_argument("--colour-intrinsics", default="",
                        help="auto or a file: read as the player does, the depth registered to "
                             "the colour camera (default: the folder's own intrinsics)")
    args = parser.parse_args()
    cv2.setNumThreads(1)                       # "on one core"
    print(cpu_gauge(), "(before)")
    reader = open_sequence(args.sequence, end=args.frames,
                           colour_intrinsics=args.colour_intrinsics or None)
    tracker = Tracking(reader.intrinsics)
    frontend, decode = [], []
    start = time.perf_counter()
    t_read = time.perf_counter()
    for frame in reader:
        decode.append(time.perf_counter() - t_read)
        t0 = time.perf_counter()
        tracker.track(frame.color, frame.depth)
        frontend.append(time.perf_counter() - t0)
        t_read = time.perf_counter()
    total = time.perf_counter() - start
    ms = np.array(frontend) * 1000
    print(f"machine: {platform.node()} {platform.machine()} python {platform.python_version()}, "
          f"OpenCV {cv2.__version__}, 1 thread; sequence {reader.path} ({len(ms)} frames, "
          f"{frame.color.shape[1]}x{frame.color.shape[0]})")
    print(f"front end: median {np.median(ms):.1f} ms/frame, p90 {np.percentile(ms, 90):.1f}, "
          f"first 100 frames {np.median(ms[:100]):.1f}, last 100 {np.median(ms[-100:]):.1f} "
          f"({len(tracker.map)} map points at the end)")
    print(f"image decoding: median {np.median(decode) * 1000:.1f} ms/frame; whole extraction "
          f"{total:.1f} s")
    print(cpu_gauge(), "(after)")


if __name__ == "__main__":
    main()
