"""How far the device's front end drifts on its own: the tracker with a map of its own that it
never forgets (ORB-SLAM's tracking and local mapping without loop closing), no edge, over a
sequence played forward and back as the live scenarios play it.

    python -m bench.front_end_drift [SEQUENCE] [--frames 1000] [--colour-focal F |
        --colour-intrinsics FILE [--depth-to-colour FILE]] [--window 200] [--errors-csv FILE]
        [--depth-baseline M]

Prints the frames it could not track, the ATE (SE(3)-aligned, as every live table), the
scale of the best similarity alignment (1 when the trajectory's size is right) and the RMS
error when each ``--window`` played frames are aligned on their own (the error without the
drift between windows: what loop closing, which removes drift, could at best reach). It is the
floor a device tracking against an edge's map built from its own poses cannot go under
without loop closing: a goal below it needs the edge to close loops, not a better policy.

``--colour-focal F`` / ``--colour-intrinsics FILE``: the colour camera when it is not the
camera of the folder's intrinsics file. 7-Scenes publishes only its depth camera's intrinsics
(focal 585, the ``camera-intrinsics.txt`` of the bundled sample) and ships colour and depth
unregistered; its colour camera's focal is about 525 (the figure relocalisation work uses,
``config/7scenes-colour-intrinsics.txt``). Each depth image is then registered to the colour
camera (:mod:`twinslam.sequences.registration`; the few-centimetre baseline between the two
is unknown and left out), as the player does with its ``colour_intrinsics`` parameter.
``--errors-csv`` writes each tracked frame's distance from the truth (after the alignment):
where along the walk the error is. ``--depth-baseline M``: the tracker's ``depth_baseline_m``
(each feature's depth reading weighed in its pose refinement; 0, the default, pixels alone).
"""

from __future__ import annotations

import argparse
import csv
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from evo.core import geometry

from bench.frames import frame_at, random_access
from bench.paths import SEVEN_SCENES
from twinslam.cli.console import HelpFormatter
from twinslam.live.tracking_quality import absolute_trajectory_error, translation_errors
from twinslam.sequences.folders import read_matrix
from twinslam.sequences.frame import SequenceError
from twinslam.sequences.opening import open_sequence
from twinslam.slam.front_end.tracking import Tracking, TrackingConfig

SEQUENCE = SEVEN_SCENES


def forward_and_back(n: int) -> list[int]:
    """The played order of ``n`` frames forward then back (the last frame once)."""
    return list(range(n)) + list(range(n - 2, -1, -1))


def similarity_scale(poses: dict[int, np.ndarray], truth: dict[int, np.ndarray]) -> float:
    """The scale of the similarity that best aligns the tracked positions with ground truth
    (evo's Umeyama): how much larger the truth's trajectory is than the tracker's."""
    common = sorted(set(poses) & set(truth))
    est = np.array([poses[k][:3, 3] for k in common]).T
    ref = np.array([truth[k][:3, 3] for k in common]).T
    return float(geometry.umeyama_alignment(est, ref, True)[2])


@dataclass
class Drift:
    """What the front end alone made of the walk."""

    played: int                         #: frames played (forward and back)
    poses: dict[int, np.ndarray]        #: play position → tracked camera-to-map pose
    truth: dict[int, np.ndarray]        #: play position → ground truth
    frames: list[int]                   #: play position → the sequence's frame

    @property
    def lost(self) -> int:
        return self.played - len(self.poses)


def drift(sequence: str, frames: int, colour_intrinsics: np.ndarray | None = None,
          depth_to_colour: np.ndarray | None = None,
          depth_baseline_m: float = TrackingConfig.depth_baseline_m) -> Drift:
    """The front end alone over ``frames`` of ``sequence`` played forward and back;
    ``colour_intrinsics``: seen by that colour camera (at ``depth_to_colour`` from the depth
    camera), the depth registered to it; ``depth_baseline_m``: the tracker's (the depth
    readings in its pose refinement; 0: pixels alone)."""
    reader = random_access(open_sequence(sequence, 0, frames, colour_intrinsics,
                                         depth_to_colour), sequence)
    order = forward_and_back(len(reader))
    tracking = Tracking(reader.intrinsics, TrackingConfig(relocalise=True,
                                                          depth_baseline_m=depth_baseline_m))
    poses: dict[int, np.ndarray] = {}
    truth: dict[int, np.ndarray] = {}
    for position, index in enumerate(order):
        frame = frame_at(reader, index, sequence)
        out = tracking.track(frame.color, frame.depth)
        if out.tracked:
            poses[position] = out.pose
        if frame.pose is not None:
            truth[position] = frame.pose
        if position % 200 == 0:
            print(f"  frame {position}/{len(order)}", flush=True)
    return Drift(len(order), poses, truth, order)


def windowed_ate(result: Drift, window: int) -> float:
    """RMS error of the frames when each run of ``window`` played frames is aligned to the
    truth on its own: the error left without the drift between windows — what closing
    loops (which removes drift, not local error) could at best bring the ATE down to."""
    squared: list[float] = []
    for start in range(0, result.played, window):
        inside = range(start, min(start + window, result.played))
        poses = {k: result.poses[k] for k in inside if k in result.poses}
        truth = {k: result.truth[k] for k in inside if k in result.truth}
        squared.extend(e ** 2 for e in translation_errors(poses, truth).values())
    return float(np.sqrt(np.mean(squared))) if squared else float("nan")


def write_errors(result: Drift, path: Path) -> None:
    """One row a tracked frame with ground truth: its play position, the sequence's frame,
    the pass and its distance from the truth after the SE(3) alignment ATE uses."""
    errors = translation_errors(result.poses, result.truth)
    half = (result.played + 1) // 2
    with path.open("w", newline="", encoding="utf-8") as fh:
        out = csv.writer(fh)
        out.writerow(["position", "frame", "pass", "translation_error_m"])
        for position, error in sorted(errors.items()):
            out.writerow([position, result.frames[position],
                          "forward" if position < half else "back", f"{error:.5f}"])


def colour_camera(sequence: str, focal: float | None, intrinsics_file: str | None
                  ) -> np.ndarray | None:
    """The colour camera the options name: a file's intrinsics, or the sequence's with
    another focal length; None: the sequence's own."""
    if intrinsics_file:
        return read_matrix(Path(intrinsics_file), 3, 3)
    if focal is None:
        return None
    k = open_sequence(sequence, 0, 1).intrinsics.copy()
    k[0, 0] = k[1, 1] = focal
    return k


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=HelpFormatter)
    parser.add_argument("sequence", nargs="?", default=str(SEQUENCE),
                        help="an RGB-D folder with ground truth (7-Scenes, TUM, SUN3D)")
    parser.add_argument("--frames", type=int, default=1000,
                        help="frames of the sequence played forward then back")
    parser.add_argument("--colour-focal", type=float, default=None, metavar="F",
                        help="the colour camera's focal in pixels when it is not the "
                        "intrinsics file's (7-Scenes: ~525, the file's 585 is the depth "
                        "camera's); the depth is registered to it")
    parser.add_argument("--colour-intrinsics", default=None, metavar="FILE",
                        help="the colour camera's 3×3 intrinsics file instead "
                        "(config/7scenes-colour-intrinsics.txt for 7-Scenes)")
    parser.add_argument("--depth-to-colour", default=None, metavar="FILE",
                        help="with a colour camera: the 4×4 transform from the depth camera's "
                        "frame to the colour camera's (default: the same place)")
    parser.add_argument("--window", type=int, default=200,
                        help="played frames aligned on their own for the drift-free figure")
    parser.add_argument("--depth-baseline", type=float, default=TrackingConfig.depth_baseline_m,
                        metavar="M", help="the tracker's depth_baseline_m: the virtual stereo "
                        "baseline its pose refinement weighs each feature's depth reading by "
                        "(0: pixels alone)")
    parser.add_argument("--errors-csv", type=Path, default=None, metavar="FILE",
                        help="write every tracked frame's distance from the truth here")
    args = parser.parse_args()
    if args.window < 3:
        parser.error(f"--window must be at least 3 frames, got {args.window}")
    if args.colour_focal is not None and not args.colour_focal > 0:
        parser.error(f"--colour-focal must be a positive number of pixels, got "
                     f"{args.colour_focal}")
    try:
        colour = colour_camera(args.sequence, args.colour_focal, args.colour_intrinsics)
        placed = (read_matrix(Path(args.depth_to_colour), 4, 4) if args.depth_to_colour
                  else None)
        result = drift(args.sequence, args.frames, colour, placed, args.depth_baseline)
    except SequenceError as exc:
        parser.error(str(exc))
    ate = absolute_trajectory_error(result.poses, result.truth)
    scale = similarity_scale(result.poses, result.truth)
    print(f"{args.frames} frames forward and back: {result.played} played, {result.lost} not "
          f"tracked, ATE {ate:.3f} m, similarity scale {scale:.3f} (depth baseline "
          f"{args.depth_baseline:g} m)")
    print(f"each {args.window} played frames aligned on their own: "
          f"{windowed_ate(result, args.window):.3f} m (the error without drift between them)")
    if args.errors_csv is not None:
        write_errors(result, args.errors_csv)
        print(f"wrote {args.errors_csv}")


if __name__ == "__main__":
    main()
