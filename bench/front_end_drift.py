"""How far the device's front end drifts on its own: the tracker with a map of its own that it
never forgets (ORB-SLAM's tracking and local mapping without loop closing), no edge, over a
sequence played forward and back as the live scenarios play it.

    python -m bench.front_end_drift [SEQUENCE] [--frames 1000]

Prints the frames it could not track and the ATE (SE(3)-aligned, as every live table). It is
the floor a device tracking against an edge's map built from its own poses cannot go under
without loop closing: a goal below it needs the edge to close loops, not a better policy.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from twinslam.cli.console import HelpFormatter
from twinslam.sequences.opening import open_sequence
from twinslam.slam.tracking import Tracking, TrackingConfig
from twinslam.slam.tracking_quality import absolute_trajectory_error

REPO = Path(__file__).resolve().parents[1]
SEQUENCE = REPO.parent / "shared" / "data" / "7scenes-1000"


def forward_and_back(n: int) -> list[int]:
    """The played order of ``n`` frames forward then back (the last frame once)."""
    return list(range(n)) + list(range(n - 2, -1, -1))


def drift(sequence: str, frames: int) -> tuple[int, int, float]:
    """(frames played, frames not tracked, ATE in metres) of the front end alone."""
    reader = open_sequence(sequence, 0, frames)
    order = forward_and_back(len(reader))
    tracking = Tracking(reader.intrinsics, TrackingConfig(relocalise=True))
    poses: dict[int, np.ndarray] = {}
    truth: dict[int, np.ndarray] = {}
    for position, index in enumerate(order):
        frame = reader.read(index)
        if frame is None:
            raise SystemExit(f"{sequence}: frame {index} cannot be read")
        out = tracking.track(frame.color, frame.depth)
        if out.tracked:
            poses[position] = out.pose
        if frame.pose is not None:
            truth[position] = frame.pose
        if position % 200 == 0:
            print(f"  frame {position}/{len(order)}", flush=True)
    return len(order), len(order) - len(poses), absolute_trajectory_error(poses, truth)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=HelpFormatter)
    parser.add_argument("sequence", nargs="?", default=str(SEQUENCE),
                        help="an RGB-D folder with ground truth (7-Scenes, TUM, SUN3D)")
    parser.add_argument("--frames", type=int, default=1000,
                        help="frames of the sequence played forward then back")
    args = parser.parse_args()
    played, lost, ate = drift(args.sequence, args.frames)
    print(f"{args.frames} frames forward and back: {played} played, {lost} not tracked, "
          f"ATE {ate:.3f} m")


if __name__ == "__main__":
    main()
