"""A loop is found where a keyframe sees a place the archive holds from long before, with the
relative pose the pose graph needs; the recent walk, and a look-alike whose points fit no one
camera pose, are no loop."""

from __future__ import annotations

import numpy as np

from tests.test_archive_relocalisation import room  # noqa: F401 (the archived room fixture)
from twinslam.slam.back_end.keyframe_archive import KeyFrameArchive
from twinslam.slam.back_end.loop_detection import detect_loop
from twinslam.slam.front_end.orb_extractor import OrbExtractor

Room = tuple[object, KeyFrameArchive, OrbExtractor]


def test_a_place_seen_long_before_closes_a_loop_with_its_relative_pose(room: Room) -> None:  # noqa: F811
    """Frame 4 of the room's walk, seen again as keyframe 1000: the archive's keyframe 0 is
    the old place, and the loop's relative pose is the true one to within centimetres."""
    seq, archive, orb = room
    frame = seq.read(4)                                        # type: ignore[attr-defined]
    feats = orb.extract(frame.color)
    loop = detect_loop(archive, 1000, feats.points, feats.descriptors,
                       seq.intrinsics)                         # type: ignore[attr-defined]
    assert loop.found, loop.reason
    assert loop.old == 0 and loop.inliers >= 50
    truth = np.linalg.inv(seq.read(0).pose) @ frame.pose      # type: ignore[attr-defined]
    assert loop.measured is not None
    assert np.linalg.norm(loop.measured[:3, 3] - truth[:3, 3]) < 0.03


def test_the_recent_walk_and_a_look_alike_are_no_loop(room: Room) -> None:  # noqa: F811
    seq, archive, orb = room
    frame = seq.read(4)                                        # type: ignore[attr-defined]
    feats = orb.extract(frame.color)
    recent = detect_loop(archive, 40, feats.points, feats.descriptors,
                         seq.intrinsics)                       # type: ignore[attr-defined]
    assert not recent.found and recent.old == -1
    # the same descriptors at shuffled pixels: a place that looks alike, geometry that fits
    # no camera
    shuffled = feats.points[np.random.default_rng(0).permutation(len(feats.points))]
    alike = detect_loop(archive, 1000, shuffled, feats.descriptors,
                        seq.intrinsics)                        # type: ignore[attr-defined]
    assert not alike.found and "inliers" in alike.reason
