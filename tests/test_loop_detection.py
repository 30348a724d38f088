"""A loop is found where a keyframe sees a place the archive holds from long before, with the
relative pose the pose graph needs; the recent walk, and a look-alike whose points fit no one
camera pose, are no loop."""

from __future__ import annotations

import dataclasses

import numpy as np

from tests.test_archive_relocalisation import room  # noqa: F401 (the archived room fixture)
from twinslam.rotations import rotation_angle_deg
from twinslam.slam.back_end.keyframe_archive import KeyFrameArchive
from twinslam.slam.back_end.loop_closing import LoopJob, LoopQuery, run_job
from twinslam.slam.back_end.loop_detection import MIN_GAP, detect_loop
from twinslam.slam.front_end.orb_extractor import OrbExtractor
from twinslam.slam.front_end.tracking import depth_at

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


def test_a_loop_is_found_though_the_recent_walk_shows_the_place_too(
        room: Room) -> None:  # noqa: F811
    """The walk came back to the room's first corner a while ago: the archive holds keyframes
    of that visit too (ids less than MIN_GAP before the query: too recent to close a loop
    with), their points made again, their descriptors as near to the query's as the old
    visit's. The loop closer looks among the keyframes a loop may close with only: the
    recent visit must neither take the votes nor, as every vote's runner-up, make Lowe's
    ratio refuse them."""
    seq, archive, orb = room
    query_id = 1000
    both = KeyFrameArchive(2 * len(archive))
    for kf in archive:
        both.add(kf, write=False)
        both.add(dataclasses.replace(kf, id=query_id - MIN_GAP + 10 + kf.id,
                                     point_ids=kf.point_ids + 1_000_000), write=False)
    frame = seq.read(4)                                        # type: ignore[attr-defined]
    feats = orb.extract(frame.color)
    query = LoopQuery(query_id, feats.points, feats.descriptors,
                      depth_at(feats.points, frame.depth, (0.2, 8.0)))
    result = run_job(LoopJob((query,), both, {}, seq.intrinsics, {}))  # type: ignore[attr-defined]
    assert result.candidate.found, result.candidate.reason
    assert result.candidate.old == 0 and result.candidate.inliers >= 50


def _turned(archive: KeyFrameArchive, degrees: float) -> KeyFrameArchive:
    """The archive with every point turned ``degrees`` about the vertical through keyframe
    0's camera — points a bundle adjustment or a fusion moved after the keyframes saw them —
    while each keyframe's pose and its own measurements stay as they were."""
    a = np.radians(degrees)
    turn = np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])
    centre = archive.get(0).pose[:3, 3]
    moved = KeyFrameArchive(len(archive))
    for kf in archive:
        moved.add(dataclasses.replace(kf, positions=(kf.positions - centre) @ turn.T + centre))
    return moved


def test_a_loop_measured_from_the_keyframes_depths_is_not_bent_by_moved_points(
        room: Room) -> None:  # noqa: F811
    """The map's points turned 2° since the old keyframe saw them: PnP against them measures
    the loop that far off, the two keyframes' own depths measure it within a centimetre and a
    fifth of a degree — the pose graph then bends the map by the drift, not by the points."""
    seq, archive, orb = room
    frame = seq.read(4)                                        # type: ignore[attr-defined]
    feats = orb.extract(frame.color)
    depths = depth_at(feats.points, frame.depth, (0.2, 8.0))
    truth = np.linalg.inv(seq.read(0).pose) @ frame.pose      # type: ignore[attr-defined]
    moved = _turned(archive, 2.0)
    by_pnp = detect_loop(moved, 1000, feats.points, feats.descriptors,
                         seq.intrinsics)                       # type: ignore[attr-defined]
    by_depth = detect_loop(moved, 1000, feats.points, feats.descriptors,
                           seq.intrinsics, depths=depths)      # type: ignore[attr-defined]
    assert by_pnp.found and by_depth.found, (by_pnp.reason, by_depth.reason)
    assert by_pnp.measured is not None and by_depth.measured is not None
    assert rotation_angle_deg((np.linalg.inv(truth) @ by_pnp.measured)[:3, :3]) > 1.0
    off = np.linalg.inv(truth) @ by_depth.measured
    assert rotation_angle_deg(off[:3, :3]) < 0.2 and np.linalg.norm(off[:3, 3]) < 0.01
    assert by_depth.old == 0 and by_depth.inliers >= 50
    # the loop's pose of the new keyframe is the old keyframe's pose times that measurement
    np.testing.assert_allclose(by_depth.pose, moved.get(0).pose @ by_depth.measured)


def test_a_look_alike_whose_depths_fit_no_motion_is_no_loop(room: Room) -> None:  # noqa: F811
    """The place's picture seen at half again its distance (a poster of it, a screen): its
    features fit the old keyframe's view — PnP accepts it — but no rigid motion carries
    its depths onto the place's."""
    seq, archive, orb = room
    frame = seq.read(4)                                        # type: ignore[attr-defined]
    feats = orb.extract(frame.color)
    depths = depth_at(feats.points, frame.depth, (0.2, 8.0))
    assert detect_loop(archive, 1000, feats.points, feats.descriptors,
                       seq.intrinsics).found                   # type: ignore[attr-defined]
    alike = detect_loop(archive, 1000, feats.points, feats.descriptors,
                        seq.intrinsics, depths=1.5 * depths)   # type: ignore[attr-defined]
    assert not alike.found and "agree in depth" in alike.reason
    # a keyframe without any depth (0: none) is measured by PnP, as without depths
    no_depth = detect_loop(archive, 1000, feats.points, feats.descriptors,
                           seq.intrinsics, depths=np.zeros(len(depths)))  # type: ignore[attr-defined]
    assert no_depth.found and no_depth.inliers >= 50
