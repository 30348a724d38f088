"""How much of one view two keyframes share: the corners a second image of a place holds that
the first holds too. Every rule that leaves out another device's keyframe because the
borrowing map has that view already — by its pose (the edge's ``lent_view_m``) or by its
points — stands on this figure, and it is lower than a pose suggests: ORB keeps the strongest
corners of each image, and a step or a turn changes which those are.

Keyframes of a sequence placed as its truth has them (``archive_pnp.true_keyframe``: their
features' depths and the true poses); for each keyframe every ``--every`` frames and each gap
of ``--gaps`` frames, the pair (keyframe, the frame that many later): how far apart the two
cameras stand and how far they turned, then three shares of the second's features — matched
to the first's in the images alone (descriptors and one epipolar geometry: no depth, no
truth); lying within ``--near-m`` of one of the first's points and alike (the same corner, as
far as depth, the truth and the descriptors tell); welded to the first's points as a
borrowing map adopting the second would weld them (``map_merging.welded``: projected, alike
in descriptor, within 10 cm). A keyframe a map could leave out as redundant
(ORB-SLAM culls its own at 90 % of its points seen by three others) would show a welded
share near 1.

    python -m bench.view_overlap [SEQUENCE] [--frames 1000] [--every 50]
                                 [--gaps 1,5,10,30,60] [--near-m 0.02] [--csv FILE]
    python -m bench.view_overlap --table FILE      # the table of a run's --csv
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import platform
from pathlib import Path

import cv2
import numpy as np
from scipy.spatial import cKDTree

from bench.archive_pnp import true_keyframe
from bench.paths import SEVEN_SCENES
from twinslam.cli.console import HelpFormatter
from twinslam.reporting import write_dict_rows
from twinslam.rotations import rotation_angle_deg
from twinslam.sequences.opening import open_sequence
from twinslam.slam.back_end.foreign_keyframes import foreign_mask
from twinslam.slam.back_end.keyframe_archive import ArchivedKeyFrame, restore_into
from twinslam.slam.back_end.keyframe_map import KeyFrameMap
from twinslam.slam.back_end.map_merging import welded
from twinslam.slam.back_end.point_fusion import FusionConfig
from twinslam.slam.camera import Camera
from twinslam.slam.descriptor_matching import hamming_rows
from twinslam.slam.front_end.orb_extractor import OrbExtractor

#: the second keyframe's point ids start here: nothing but geometry and descriptors relates
#: its points to the first's
SECOND_IDS = 1 << 30
#: the first keyframe's points near one of the second's that are compared with it
NEIGHBOURS = 4
#: Lowe's ratio of the image matching
RATIO = 0.8
#: two descriptors alike: within welding's Hamming distance
MAX_HAMMING = FusionConfig().max_hamming


@dataclasses.dataclass(frozen=True)
class Overlap:
    """One pair of keyframes of a place, the second ``gap`` frames after the first."""

    first: int
    gap: int
    apart_m: float                 #: camera centres apart
    turned_deg: float              #: the rotation between the cameras
    points: int                    #: the second keyframe's points (features with a depth)
    #: share of them within near_m of one of the first's that looks alike
    same_corner: float
    welded: float                  #: share welded to the first's points
    #: share matched in the images alone: alike (Lowe's ratio) and consistent with one
    #: epipolar geometry (RANSAC) — no depth, no truth
    matched: float


def _same_corners(first: ArchivedKeyFrame, second: ArchivedKeyFrame, near_m: float
                  ) -> np.ndarray:
    """Which of ``second``'s points is a corner ``first`` holds: one of ``first``'s points lies
    within ``near_m`` of it and looks alike (descriptors within welding's Hamming distance). A
    room's surfaces hold a point every few centimetres: nearness alone would pair corners by
    chance."""
    distances, rows = cKDTree(first.positions).query(second.positions, k=NEIGHBOURS,
                                                      distance_upper_bound=near_m)
    alike = np.zeros(len(second.point_ids), dtype=bool)
    for column in range(NEIGHBOURS):
        near = np.isfinite(distances[:, column])
        if not near.any():
            break
        apart = hamming_rows(second.descriptors[near], first.descriptors[rows[near, column]])
        alike[np.flatnonzero(near)] |= apart <= MAX_HAMMING
    return alike


def _matched_in_images(first: ArchivedKeyFrame, second: ArchivedKeyFrame) -> int:
    """How many of ``second``'s features match one of ``first``'s by descriptor (Lowe's ratio
    0.8, welding's Hamming distance at most; several may match one of ``first``'s, unlike
    :func:`~twinslam.slam.descriptor_matching.match_descriptors`) where one fundamental matrix
    holds for them (RANSAC, 2 px): the overlap as the two images alone tell it."""
    pairs = cv2.BFMatcher(cv2.NORM_HAMMING).knnMatch(second.descriptors, first.descriptors, k=2)
    good = [m[0] for m in pairs if len(m) == 2 and m[0].distance < RATIO * m[1].distance
            and m[0].distance <= MAX_HAMMING]
    if len(good) < 8:
        return 0
    theirs = second.measurements[[m.queryIdx for m in good], :2].astype(np.float32)
    ours = first.measurements[[m.trainIdx for m in good], :2].astype(np.float32)
    _, inliers = cv2.findFundamentalMat(theirs, ours, method=cv2.FM_RANSAC,
                                        ransacReprojThreshold=2.0, confidence=0.999)
    return 0 if inliers is None else int(inliers.sum())


def overlap(first: ArchivedKeyFrame, second: ArchivedKeyFrame, camera: Camera, near_m: float
            ) -> Overlap:
    """How much of ``first``'s view ``second`` holds (see the module's docstring)."""
    apart = float(np.linalg.norm(first.pose[:3, 3] - second.pose[:3, 3]))
    turned = rotation_angle_deg(first.pose[:3, :3].T @ second.pose[:3, :3])
    n = len(second.point_ids)
    if n == 0 or len(first.point_ids) == 0:
        return Overlap(first.id, second.id - first.id, apart, turned, n, 0.0, 0.0, 0.0)
    same = float(_same_corners(first, second, near_m).mean())
    held = KeyFrameMap()
    held.next_point_id = int(first.point_ids.max()) + 1
    restore_into(held, first)
    theirs = dataclasses.replace(second, point_ids=second.point_ids + SECOND_IDS)
    adopted = welded(theirs, 0, held, camera, slot=0)
    return Overlap(first.id, second.id - first.id, apart, turned, n, same,
                   float((~foreign_mask(adopted.point_ids)).mean()),
                   _matched_in_images(first, second) / n)


def _keyframes(sequence: str, frames: int, wanted: set[int]) -> tuple[dict[int, ArchivedKeyFrame],
                                                                      np.ndarray]:
    """The ``wanted`` frames of the sequence's first ``frames`` as true keyframes, read in one
    pass (a dataset on disk is read in order), and the sequence's intrinsics."""
    seq = open_sequence(sequence, 0, frames)
    orb = OrbExtractor()
    kept: dict[int, ArchivedKeyFrame] = {}
    intrinsics: np.ndarray | None = None
    for index, frame in enumerate(seq):
        if index >= frames:
            break
        intrinsics = frame.intrinsics
        if index in wanted:
            if frame.depth is None or frame.pose is None:
                raise SystemExit(f"{sequence}: frame {index} ({frame.name or 'unnamed'}) has no "
                                 f"{'depth' if frame.depth is None else 'true pose'}: the "
                                 "keyframes are placed by their depth and their truth")
            kept[index] = true_keyframe(frame, index, frame.intrinsics, orb, 1, 0)
    if intrinsics is None:
        raise SystemExit(f"{sequence}: no frames")
    return kept, intrinsics


def table(pairs: list[Overlap]) -> list[str]:
    """The markdown table of ``pairs``: by frames apart, the medians over its pairs."""
    lines = ["| frames apart | pairs | cameras apart, m | turned, deg | points | matched in the "
             "images | same corner | welded | welded ≥ 0.9 |",
             "|---|---|---|---|---|---|---|---|---|"]
    for gap in sorted({p.gap for p in pairs}):
        at = [p for p in pairs if p.gap == gap]
        lines.append(f"| {gap} | {len(at)} | {np.median([p.apart_m for p in at]):.3f} | "
                     f"{np.median([p.turned_deg for p in at]):.1f} | "
                     f"{np.median([p.points for p in at]):.0f} | "
                     f"{np.median([p.matched for p in at]):.2f} | "
                     f"{np.median([p.same_corner for p in at]):.2f} | "
                     f"{np.median([p.welded for p in at]):.2f} | "
                     f"{sum(p.welded >= 0.9 for p in at)} |")
    return lines


def read_pairs(path: Path) -> list[Overlap]:
    """The pairs a run wrote with ``--csv``."""
    with path.open(encoding="utf-8", newline="") as fh:
        return [Overlap(int(row["first"]), int(row["gap"]), float(row["apart_m"]),
                        float(row["turned_deg"]), int(row["points"]),
                        float(row["same_corner"]), float(row["welded"]), float(row["matched"]))
                for row in csv.DictReader(fh)]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=HelpFormatter)
    parser.add_argument("sequence", nargs="?", default=str(SEVEN_SCENES),
                        help="an RGB-D sequence with depth and true poses (default: the "
                             "bundled 7-Scenes sample; synthetic:N for the synthetic room)")
    parser.add_argument("--frames", type=int, default=1000, help="frames of it read")
    parser.add_argument("--every", type=int, default=50,
                        help="a first keyframe every this many frames")
    parser.add_argument("--gaps", default="1,5,10,30,60",
                        help="frames between the two keyframes of a pair, comma-separated")
    parser.add_argument("--near-m", type=float, default=0.02,
                        help="metres within which two keyframes' points are one corner")
    parser.add_argument("--csv", type=Path, help="also write every pair here")
    parser.add_argument("--table", type=Path, metavar="CSV",
                        help="print the table of the pairs a run wrote with --csv, and stop")
    args = parser.parse_args()
    if args.table:
        print("\n".join(table(read_pairs(args.table))))
        return
    try:
        gaps = sorted({int(g) for g in args.gaps.split(",")})
    except ValueError:
        parser.error(f"--gaps: frame counts separated by commas, got {args.gaps!r}")
    if not gaps or gaps[0] < 1 or args.every < 1 or args.frames <= gaps[-1] or args.near_m <= 0:
        parser.error("--gaps of 1 frame or more and fewer than --frames, --every 1 or more, "
                     "--near-m above 0")
    firsts = list(range(0, args.frames - gaps[-1], args.every))
    wanted = {f + g for f in firsts for g in (0, *gaps)}
    print(f"{args.sequence}: {len(firsts)} first keyframes, gaps {gaps}, "
          f"{len(wanted)} frames to extract", flush=True)
    keyframes, intrinsics = _keyframes(args.sequence, args.frames, wanted)
    camera = Camera(intrinsics)
    pairs = [overlap(keyframes[f], keyframes[f + g], camera, args.near_m)
             for f in firsts for g in gaps if f in keyframes and f + g in keyframes]
    print(f"\n{platform.node()}, {args.sequence}, a first keyframe every {args.every} frames "
          f"(medians over the pairs; the same corner: within {args.near_m * 100:.0f} cm and "
          "alike):\n")
    print("\n".join(table(pairs)))
    if args.csv:
        write_dict_rows(args.csv, [dataclasses.asdict(p) for p in pairs])
        print(f"\nwrote {args.csv}")


if __name__ == "__main__":
    main()
