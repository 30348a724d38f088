"""Another device's keyframe keeps the camera that took it. Devices of one place are rarely one
camera model: a keyframe lent by a device whose focal length differs measured its pixels with
its own intrinsics, and every reader of those pixels — the welding, the adjustment, the loop's
and the merge's depth alignment, the fusion of a restored keyframe — must read them with those.
Here: the intrinsics survive the archive's files and the map's checkpoint, and the depth
alignment of a keyframe to another device's recovers their true relative pose only with the
other's camera."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from twinslam.slam.back_end.archive_relocalisation import ArchiveRelocalisationConfig
from twinslam.slam.back_end.keyframe_archive import ArchivedKeyFrame, restore_into
from twinslam.slam.back_end.keyframe_map import KeyFrameMap
from twinslam.slam.back_end.loop_detection import measure_between

OWN = np.array([[525.0, 0, 319.5], [0, 525.0, 239.5], [0, 0, 1]])
OTHER = np.array([[450.0, 0, 319.5], [0, 450.0, 239.5], [0, 0, 1]])


def _seen(points: np.ndarray, pose: np.ndarray, k: np.ndarray) -> np.ndarray:
    """(u, v, depth) of world ``points`` in a camera at ``pose`` (camera-to-world) of ``k``."""
    cw = np.linalg.inv(pose)
    cam = points @ cw[:3, :3].T + cw[:3, 3]
    uv = cam @ k.T
    return np.column_stack([uv[:, :2] / uv[:, 2:], cam[:, 2]])


def _other_devices_keyframe(rng: np.random.Generator, n: int = 120
                            ) -> tuple[ArchivedKeyFrame, np.ndarray]:
    """A keyframe another device's camera (OTHER) took at the origin of n points 2-4 m ahead;
    (it, the points)."""
    points = rng.uniform([-1.2, -0.9, 2.0], [1.2, 0.9, 4.0], (n, 3))
    seen = _seen(points, np.eye(4), OTHER)
    return ArchivedKeyFrame(7, np.eye(4), np.arange(1, n + 1), points,
                            rng.integers(0, 256, (n, 32), dtype=np.uint8), seen, 3,
                            OTHER.copy()), points


def test_another_devices_camera_survives_the_archive_file_and_the_maps_checkpoint(
        tmp_path: Path) -> None:
    """Saved and read back, the archived keyframe keeps its intrinsics; restored into a map,
    the map's keyframe carries them, through the map's checkpoint too; one of the map's own
    device keeps none (the map's own camera)."""
    kf, _ = _other_devices_keyframe(np.random.default_rng(1))
    kf.save(tmp_path / "kf.npz")
    back = ArchivedKeyFrame.load(tmp_path / "kf.npz")
    np.testing.assert_array_equal(back.intrinsics, OTHER)
    np.testing.assert_array_equal(back.camera(OWN), OTHER)
    m = KeyFrameMap()
    m.next_point_id = 1000                     # its points were the map's before it left
    restore_into(m, back)
    m.add_keyframe(8, np.eye(4))
    np.testing.assert_array_equal(m.keyframes[7].intrinsics, OTHER)
    assert m.keyframes[8].intrinsics is None
    m.save(tmp_path / "map.npz")
    loaded, _ = KeyFrameMap.load(tmp_path / "map.npz")
    np.testing.assert_array_equal(loaded.keyframes[7].intrinsics, OTHER)
    assert loaded.keyframes[8].intrinsics is None
    again = ArchivedKeyFrame.of(loaded, 7, slot=9)
    np.testing.assert_array_equal(again.intrinsics, OTHER)
    own = ArchivedKeyFrame.of(loaded, 8, slot=9)
    assert own.intrinsics is None and own.camera(OWN) is OWN


def test_a_keyframe_is_aligned_to_another_devices_by_depth_only_with_that_devices_camera(
) -> None:
    """This device's keyframe 0.3 m to the right of another device's: the depth alignment
    of the two recovers that step within a millimetre when it lifts the other's pixels with
    the other's camera, and misses by centimetres when it lifts them with its own."""
    rng = np.random.default_rng(2)
    old, points = _other_devices_keyframe(rng)
    pose = np.eye(4)
    pose[0, 3] = 0.3
    seen = _seen(points, pose, OWN)
    config = ArchiveRelocalisationConfig(min_inliers=30)
    right = measure_between(old, seen[:, :2], old.descriptors, seen[:, 2], OWN, pose, config,
                            old.camera(OWN))
    wrong = measure_between(old, seen[:, :2], old.descriptors, seen[:, 2], OWN, pose, config)
    assert right.pose is not None
    assert np.linalg.norm(right.pose[:3, 3] - pose[:3, 3]) < 0.001
    assert wrong.pose is None or np.linalg.norm(wrong.pose[:3, 3] - pose[:3, 3]) > 0.02


def test_the_edges_adjustment_keeps_a_copy_taken_by_another_camera_where_it_is() -> None:
    """An edge map of this device's keyframes 0-3 and a copy of another device's keyframe
    (its camera OTHER), all seeing 150 points where they are (a third of a pixel's noise):
    the local adjustment moves nothing by 5 mm and drops none of the copy's observations —
    read with this device's camera, they would be outliers and move the copy half a metre
    (an answer the edge refuses)."""
    from twinslam.slam.back_end.foreign_keyframes import foreign_tag
    from twinslam.slam.back_end.map_back_end import BackEndConfig, MapBackEnd

    rng = np.random.default_rng(5)
    points = rng.uniform([-1.0, -0.8, 2.5], [1.5, 0.8, 4.0], (150, 3))
    back_end = MapBackEnd(BackEndConfig(ba_window=3, ba_points=None), intrinsics=OWN)
    m = back_end.map
    ids = m.add_points(points, rng.integers(0, 256, (150, 32), dtype=np.uint8))
    copy = foreign_tag(1) | 40
    for kf, x, camera in [(0, 0.0, None), (1, 0.1, None), (2, 0.2, None), (3, 0.3, None),
                          (copy, 0.15, OTHER)]:
        pose = np.eye(4)
        pose[0, 3] = x
        m.add_keyframe(kf, pose, camera)
        seen = _seen(points, pose, OWN if camera is None else camera)
        seen[:, :2] += rng.normal(0.0, 0.3, (len(points), 2))      # a detector's noise
        m.observe_many(kf, ids, seen[:, :2].tolist(), seen[:, 2].tolist())
    before = {k: kf.pose.copy() for k, kf in m.keyframes.items()}
    result = back_end.optimise()
    assert result is not None and not result.refused
    assert len(m.keyframes[copy].points) == 150 and not result.outliers
    for k, pose in before.items():
        assert np.linalg.norm(m.keyframes[k].pose[:3, 3] - pose[:3, 3]) < 0.005, k


def test_a_restored_copy_is_fused_with_the_maps_points_through_its_own_camera() -> None:
    """Another device's keyframe (its camera OTHER) archived with 120 points this device's
    keyframe 0 sees too, under the other device's ids: restored, its points are found to be
    the map's — projected into it with its camera they land where it saw them — and fused,
    nearly all of them."""
    from twinslam.slam.back_end.foreign_keyframes import foreign_tag
    from twinslam.slam.back_end.map_back_end import BackEndConfig, MapBackEnd

    rng = np.random.default_rng(6)
    copy, points = _other_devices_keyframe(rng)
    back_end = MapBackEnd(BackEndConfig(point_fusion=True), intrinsics=OWN)
    m = back_end.map
    ids = m.add_points(copy.positions, copy.descriptors)
    pose = np.eye(4)
    pose[0, 3] = 0.1
    seen = _seen(copy.positions, pose, OWN)
    m.add_keyframe(0, pose)
    m.observe_many(0, ids, seen[:, :2].tolist(), seen[:, 2].tolist())
    tag = foreign_tag(1)
    back_end.archive.add(ArchivedKeyFrame(tag | copy.id, copy.pose, copy.point_ids | tag,
                                          copy.positions, copy.descriptors,
                                          copy.measurements, 0, OTHER.copy()))
    _, fused = back_end.restore([tag | copy.id], [], slot=1)
    assert fused >= 0.9 * len(points)
    assert len(m.points) <= len(ids) + 0.1 * len(points)
