"""How far the device's front end drifts on its own: the tracker with a map of its own that it
never forgets (ORB-SLAM's tracking and local mapping without loop closing), no edge, over a
sequence played forward and back as the live scenarios play it.

    python -m bench.front_end_drift [SEQUENCE] [--frames 1000] [--colour-focal F]

Prints the frames it could not track, the ATE (SE(3)-aligned, as every live table) and the
scale of the best similarity alignment (1 when the trajectory's size is right). It is the
floor a device tracking against an edge's map built from its own poses cannot go under
without loop closing: a goal below it needs the edge to close loops, not a better policy.

``--colour-focal F``: the colour camera's focal length in pixels when it is not the depth
camera's. 7-Scenes publishes only its depth camera's intrinsics (focal 585, the
``camera-intrinsics.txt`` of the bundled sample) and ships colour and depth unregistered; its
colour camera's focal is about 525 (the figure re-localisation work uses). With F each depth
image is registered to the colour camera (its points moved to the colour camera's pixels,
the nearest kept; the few-centimetre baseline between the two is unknown and left out) and
the colour images are tracked with focal F.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from evo.core import geometry

from twinslam.cli.console import HelpFormatter
from twinslam.live.tracking_quality import absolute_trajectory_error
from twinslam.sequences.opening import open_sequence
from twinslam.slam.front_end.tracking import Tracking, TrackingConfig

REPO = Path(__file__).resolve().parents[1]
SEQUENCE = REPO.parent / "shared" / "data" / "7scenes-1000"


def forward_and_back(n: int) -> list[int]:
    """The played order of ``n`` frames forward then back (the last frame once)."""
    return list(range(n)) + list(range(n - 2, -1, -1))


def register_depth(depth: np.ndarray, depth_intrinsics: np.ndarray,
                   colour_intrinsics: np.ndarray) -> np.ndarray:
    """``depth`` (metres, 0 = none) of a camera with ``depth_intrinsics`` as a camera at the
    same place with ``colour_intrinsics`` sees it: each reading moved to the pixel its point
    projects to, the nearest kept where several land; pixels no reading lands on are 0."""
    h, w = depth.shape
    v, u = np.nonzero(depth > 0)
    z = depth[v, u].astype(np.float64)
    kd, kc = depth_intrinsics, colour_intrinsics
    x = (u - kd[0, 2]) / kd[0, 0]
    y = (v - kd[1, 2]) / kd[1, 1]
    uc = np.rint(kc[0, 0] * x + kc[0, 2]).astype(np.int64)
    vc = np.rint(kc[1, 1] * y + kc[1, 2]).astype(np.int64)
    inside = (uc >= 0) & (uc < w) & (vc >= 0) & (vc < h)
    out = np.full((h, w), np.inf)
    np.minimum.at(out, (vc[inside], uc[inside]), z[inside])
    out[np.isinf(out)] = 0.0
    return out.astype(depth.dtype)


def similarity_scale(poses: dict[int, np.ndarray], truth: dict[int, np.ndarray]) -> float:
    """The scale of the similarity that best aligns the tracked positions with ground truth
    (evo's Umeyama): how much larger the truth's trajectory is than the tracker's."""
    common = sorted(set(poses) & set(truth))
    est = np.array([poses[k][:3, 3] for k in common]).T
    ref = np.array([truth[k][:3, 3] for k in common]).T
    return float(geometry.umeyama_alignment(est, ref, True)[2])


def drift(sequence: str, frames: int, colour_focal: float | None = None
          ) -> tuple[int, int, float, float]:
    """(frames played, frames not tracked, ATE in metres, similarity scale) of the front end
    alone; ``colour_focal``: track with that focal, the depth registered to it."""
    reader = open_sequence(sequence, 0, frames)
    order = forward_and_back(len(reader))
    intrinsics = reader.intrinsics
    if colour_focal is not None:
        intrinsics = intrinsics.copy()
        intrinsics[0, 0] = intrinsics[1, 1] = colour_focal
    tracking = Tracking(intrinsics, TrackingConfig(relocalise=True))
    poses: dict[int, np.ndarray] = {}
    truth: dict[int, np.ndarray] = {}
    for position, index in enumerate(order):
        frame = reader.read(index)
        if frame is None:
            raise SystemExit(f"{sequence}: frame {index} cannot be read")
        depth = (frame.depth if colour_focal is None
                 else register_depth(frame.depth, reader.intrinsics, intrinsics))
        out = tracking.track(frame.color, depth)
        if out.tracked:
            poses[position] = out.pose
        if frame.pose is not None:
            truth[position] = frame.pose
        if position % 200 == 0:
            print(f"  frame {position}/{len(order)}", flush=True)
    return (len(order), len(order) - len(poses), absolute_trajectory_error(poses, truth),
            similarity_scale(poses, truth))


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
    args = parser.parse_args()
    if args.colour_focal is not None and not args.colour_focal > 0:
        parser.error(f"--colour-focal must be a positive number of pixels, got "
                     f"{args.colour_focal}")
    played, lost, ate, scale = drift(args.sequence, args.frames, args.colour_focal)
    print(f"{args.frames} frames forward and back: {played} played, {lost} not tracked, "
          f"ATE {ate:.3f} m, similarity scale {scale:.3f}")


if __name__ == "__main__":
    main()
