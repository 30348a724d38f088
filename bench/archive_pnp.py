"""How the archive's PnP fares when most of a frame's matches are wrong: the relocalisation,
loop and merge searches solve a frame's pose from its descriptors matched to archived points
(:mod:`twinslam.slam.back_end.archive_relocalisation`), and between two visits of a place
many of those matches are wrong — the look changed, a pattern repeats.

An archive of keyframes every 30 frames of the synthetic room (points placed by depth and
the true pose); for each query frame and each share of moved features, a few draws in which
that share of the frame's features is moved to another feature's pixel (descriptors kept: they
still match, at the wrong place). Each solver (``ArchiveRelocalisationConfig.solver``)
locates every draw; printed per share: the draws found within ``--near`` of the truth, found
farther off (a wrong pose accepted), and not found, with the median time a search.

    python -m bench.archive_pnp [--queries 4,127,251] [--shares 0.5,0.67,0.75,0.8,0.85]
                                [--draws 5] [--solvers epnp,usac] [--csv FILE]
"""

from __future__ import annotations

import argparse
import platform
import time
from pathlib import Path

import numpy as np

from twinslam.cli.console import HelpFormatter
from twinslam.reporting import write_dict_rows
from twinslam.sequences.frame import RandomAccessSequence, RgbdFrame
from twinslam.sequences.opening import open_sequence
from twinslam.slam.back_end.archive_relocalisation import (
    SOLVERS,
    ArchiveRelocalisationConfig,
    locate_in_archive,
)
from twinslam.slam.back_end.keyframe_archive import ArchivedKeyFrame, KeyFrameArchive
from twinslam.slam.front_end.orb_extractor import OrbExtractor
from twinslam.slam.front_end.tracking import depth_at
from twinslam.slam.projection_matching import back_project


def true_keyframe(frame: RgbdFrame, index: int, intrinsics: np.ndarray, orb: OrbExtractor,
                  first_point: int, slot: int) -> ArchivedKeyFrame:
    """Frame ``index`` as a map would archive it were its poses the sequence's truth: its ORB
    features with a depth, placed by that depth and the frame's true pose, numbered from
    ``first_point`` (the keyframe's error is then the depth's and the truth's own)."""
    assert frame.depth is not None and frame.pose is not None, "a frame with depth and truth"
    feats = orb.extract(frame.color)
    z = depth_at(feats.points, frame.depth, (0.2, 8.0))
    keep = z > 0
    world = back_project(feats.points[keep], z[keep], intrinsics, frame.pose)
    n = int(keep.sum())
    return ArchivedKeyFrame(index, frame.pose.copy(), np.arange(first_point, first_point + n),
                            world, feats.descriptors[keep],
                            np.column_stack([feats.points[keep], z[keep]]), slot)


def room_archive(frames: int = 300, every: int = 30) -> tuple[object, KeyFrameArchive]:
    """The synthetic room and an archive of a keyframe every ``every`` frames."""
    seq = open_sequence(f"synthetic:{frames}", 0, frames)
    assert isinstance(seq, RandomAccessSequence)        # a synthetic world reads any frame
    orb = OrbExtractor()
    archive = KeyFrameArchive(100)
    first = 1
    for slot, index in enumerate(range(0, frames, every)):
        frame = seq.read(index)
        # the synthetic world renders every frame with its depth and its true pose
        assert frame is not None
        kf = true_keyframe(frame, index, seq.intrinsics, orb, first, slot)
        archive.add(kf)
        first += len(kf.point_ids)
    return seq, archive


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=HelpFormatter)
    parser.add_argument("--queries", default="4,127,251",
                        help="frames of the room's walk to locate, comma-separated")
    parser.add_argument("--shares", default="0.5,0.67,0.75,0.8,0.85",
                        help="shares of each frame's features moved, comma-separated")
    parser.add_argument("--draws", type=int, default=5, help="random draws a share and frame")
    parser.add_argument("--solvers", default=",".join(SOLVERS),
                        help=f"the PnP solvers compared ({', '.join(SOLVERS)})")
    parser.add_argument("--near", type=float, default=0.03,
                        help="metres from the true camera within which a pose counts as right")
    parser.add_argument("--csv", type=Path, default=None, help="also write every draw here")
    args = parser.parse_args()
    solvers = args.solvers.split(",")
    unknown = [s for s in solvers if s not in SOLVERS]
    if unknown:
        parser.error(f"--solvers: {', '.join(unknown)} unknown; one of {', '.join(SOLVERS)}")
    queries = [int(q) for q in args.queries.split(",")]
    shares = [float(s) for s in args.shares.split(",")]
    print(f"machine: {platform.machine()}, python {platform.python_version()}; building the "
          "room's archive", flush=True)
    seq, archive = room_archive()
    orb = OrbExtractor()
    rows = []
    for query in queries:
        frame = seq.read(query)                                # type: ignore[attr-defined]
        feats = orb.extract(frame.color)
        for share in shares:
            for draw in range(args.draws):
                rng = np.random.default_rng(draw)
                xy = feats.points.copy()
                moved = rng.random(len(xy)) < share
                xy[moved] = rng.permutation(xy[moved])
                for solver in solvers:
                    config = ArchiveRelocalisationConfig(solver=solver)
                    t0 = time.perf_counter()
                    found = locate_in_archive(archive, xy, feats.descriptors,
                                              seq.intrinsics, config)  # type: ignore[attr-defined]
                    ms = (time.perf_counter() - t0) * 1e3
                    off = (float(np.linalg.norm(found.pose[:3, 3] - frame.pose[:3, 3]))
                           if found.pose is not None else float("nan"))
                    rows.append({"query": query, "share_moved": share, "draw": draw,
                                 "solver": solver, "found": int(found.found),
                                 "inliers": found.inliers, "off_m": off, "ms": ms})
    print(f"{'share moved':>11} {'solver':>6} {'right':>6} {'wrong pose':>10} "
          f"{'none':>5} {'ms median':>9}")
    for share in shares:
        for solver in solvers:
            mine = [r for r in rows if r["share_moved"] == share and r["solver"] == solver]
            right = sum(1 for r in mine if r["found"] and r["off_m"] <= args.near)
            wrong = sum(1 for r in mine if r["found"] and r["off_m"] > args.near)
            print(f"{share:>11.2f} {solver:>6} {right:>3}/{len(mine):<2} {wrong:>10} "
                  f"{len(mine) - right - wrong:>5} "
                  f"{float(np.median([r['ms'] for r in mine])):>9.1f}", flush=True)
    if args.csv:
        write_dict_rows(args.csv, rows)
        print(f"wrote {args.csv}")


if __name__ == "__main__":
    main()
