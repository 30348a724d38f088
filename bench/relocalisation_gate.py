"""How many inliers a right and a wrong relocalisation keep: the data behind the device's pose
gate (``TrackingConfig.reloc_min_inliers``).

The device's tracker builds its own map over the first ``--map-frames`` frames of an RGB-D
sequence with ground truth (the bundled 7-Scenes walk), then tries the relocalisation search
(descriptor matching against every map point, PnP RANSAC, no pose prior) on every
``--every``-th later frame, and on every frame of a *different* scene (``--other``: any pose
found there is wrong by construction). Each attempt that RANSAC accepts with the tracker's
``min_inliers`` is a row: its inliers and its position error against the ground truth,
expressed in the device's frame (the first frame is the origin). A threshold is safe when no
wrong relocalisation keeps that many inliers and most right ones do.

    python -m bench.relocalisation_gate ../shared/data/7scenes-1000 \\
        --other ../shared/data/sun3d-mit_w85k1-whole_apartment-30 --csv build/reloc_gate.csv
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from bench.frames import frame_at, random_access
from twinslam.live.tracking_quality import JUMP_M
from twinslam.reporting import write_csv
from twinslam.sequences.opening import open_sequence
from twinslam.slam.front_end.tracking import Tracking, TrackingConfig


def attempts(tracking: Tracking, sequence_path: str, frames: range, origin: np.ndarray | None,
             source: str) -> list[list[Any]]:
    """One row per accepted relocalisation attempt of ``frames``: (source, frame, inliers,
    error m); the error is NaN for a frame without ground truth, inf for another scene."""
    seq = random_access(open_sequence(sequence_path), sequence_path)
    rows: list[list[Any]] = []
    for i in frames:
        if i >= len(seq):
            break
        frame = frame_at(seq, i, sequence_path)
        feats = tracking.extractor.extract(frame.color)
        _, _, pose, inliers = tracking.relocalise(feats)
        if pose is None:
            continue
        if origin is None:
            error = float("inf")
        elif frame.pose is None:
            error = float("nan")
        else:
            truth = np.linalg.inv(origin) @ frame.pose
            error = float(np.linalg.norm(pose[:3, 3] - truth[:3, 3]))
        rows.append([source, i, int(inliers.sum()), round(error, 4)])
    return rows


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("sequence", help="an RGB-D sequence with ground truth (the map)")
    parser.add_argument("--other", default="",
                        help="a sequence of another place: every pose found there is wrong")
    parser.add_argument("--map-frames", type=int, default=500,
                        help="frames tracked to build the map; default %(default)s")
    parser.add_argument("--every", type=int, default=5,
                        help="try every this-many-th later frame; default %(default)s")
    parser.add_argument("--csv", type=Path, default=Path("build/relocalisation_gate.csv"),
                        help="where the rows go; default %(default)s")
    args = parser.parse_args(argv)
    cv2.setNumThreads(1)
    seq = random_access(open_sequence(args.sequence), args.sequence)
    tracking = Tracking(seq.intrinsics, TrackingConfig(relocalise=False))
    origin = frame_at(seq, 0, args.sequence).pose
    for i in range(min(args.map_frames, len(seq))):
        frame = frame_at(seq, i, args.sequence)
        tracking.track(frame.color, frame.depth)
    print(f"map: {int(tracking.map.active.sum())} active points after {args.map_frames} frames",
          flush=True)
    rows = attempts(tracking, args.sequence, range(args.map_frames, len(seq), args.every),
                    origin, "same place")
    if args.other:
        rows += attempts(tracking, args.other, range(10_000), None, "other place")
    write_csv(args.csv, ["source", "frame", "inliers", "error_m"], rows)
    right = np.array([r[2] for r in rows if r[0] == "same place" and float(r[3]) <= JUMP_M])
    wrong = np.array([r[2] for r in rows if r[0] == "other place" or float(r[3]) > JUMP_M])
    print(f"accepted at {tracking.config.min_inliers} inliers: {len(right)} right (error <= "
          f"{JUMP_M} m), {len(wrong)} wrong; wrote {args.csv}")
    for threshold in (15, 20, 30, 40, 50, 60, 80):
        print(f"  >= {threshold:3d} inliers: right kept {int((right >= threshold).sum()):4d}, "
              f"wrong kept {int((wrong >= threshold).sum()):4d}"
              + (f" (wrong max {int(wrong.max())})" if len(wrong) else ""))


if __name__ == "__main__":
    main()
