"""Sequence readers on the real samples (when ../shared/data is present) and on small SUN3D /
TUM RGB-D / 7-Scenes folders the tests build themselves."""

from __future__ import annotations

import logging
from pathlib import Path

import cv2
import numpy as np
import pytest

from tests.data_paths import SEVEN, SUN3D, needs_seven, needs_sun3d
from twinslam.sequences.folders import decode_depth
from twinslam.sequences.frame import SequenceError
from twinslam.sequences.opening import open_sequence

K = np.array([[500.0, 0, 16], [0, 500.0, 12], [0, 0, 1]])


def _write_matrix(path: Path, m: np.ndarray) -> None:
    np.savetxt(path, m)


def _colour(seed: int) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 255, (24, 32, 3), dtype=np.uint8)


@needs_seven
def test_seven_scenes_sample_reads_with_metric_depth_and_ground_truth() -> None:
    reader = open_sequence(SEVEN)
    assert len(reader) == 1000 and reader.kind == "7scenes"
    assert reader.intrinsics[0, 0] == 585.0
    frames = [f for _, f in zip(range(3), reader, strict=False)]
    f = frames[2]
    assert f.color.shape == (480, 640, 3) and f.color.dtype == np.uint8
    valid = f.depth[f.depth > 0]
    assert f.depth.dtype == np.float32 and 0.3 < np.median(valid) < 5.0   # metres, not mm
    assert f.pose.shape == (4, 4) and np.allclose(f.pose[3], [0, 0, 0, 1])
    assert f.stamp == pytest.approx(2 / 30.0)
    assert reader.skipped == []


@needs_sun3d
def test_sun3d_sample_decodes_rotated_depth_and_partial_extrinsics() -> None:
    reader = open_sequence(SUN3D)
    assert len(reader) == 30 and reader.kind == "sun3d"
    assert reader.intrinsics[0, 0] == pytest.approx(570.3422, abs=1e-3)
    has_pose = [p is not None for p in reader.poses]
    assert has_pose[:7] == [True] * 7 and not any(has_pose[7:])   # the file covers 7 frames
    f = next(iter(reader))
    valid = f.depth[f.depth > 0]
    assert 0.3 < np.median(valid) < 6.0, "bit-rotated depth decoded to metres"
    assert np.all(np.diff(reader.stamps) > 0)


def test_sun3d_depth_bit_rotation_is_inverted_exactly() -> None:
    mm = np.array([[0, 1, 1234, 8191]], dtype=np.uint32)
    stored = ((mm << 3) | (mm >> 13)) & 0xFFFF          # how SUN3D writes millimetres
    got = decode_depth(stored.astype(np.uint16), "sun3d")
    np.testing.assert_allclose(got, mm / 1000.0)
    assert decode_depth(np.array([[65535, 1500]], np.uint16), "mm").tolist() == [[0.0, 1.5]]


def _sun3d_folder(root: Path) -> Path:
    (root / "image").mkdir(parents=True)
    (root / "depth").mkdir()
    (root / "extrinsics").mkdir()
    _write_matrix(root / "intrinsics.txt", K)
    for i in range(4):
        stamp = 33_000 * i
        cv2.imwrite(str(root / "image" / f"{i + 1:07d}-{stamp:012d}.jpg"), _colour(i))
        mm = np.full((24, 32), 1000 + 100 * i, dtype=np.uint32)
        rotated = ((mm << 3) | (mm >> 13)) & 0xFFFF
        # depth stamped 5 ms after its colour frame: paired by nearest time
        cv2.imwrite(str(root / "depth" / f"{i + 1:07d}-{stamp + 5000:012d}.png"),
                    rotated.astype(np.uint16))
    old = np.tile(np.hstack([np.eye(3), np.zeros((3, 1))]), (4, 1))
    new = np.tile(np.hstack([np.eye(3), np.ones((3, 1))]), (2, 1))   # newest, covers 2 frames
    _write_matrix(root / "extrinsics" / "20130101000000.txt", old)
    _write_matrix(root / "extrinsics" / "20140101000000.txt", new)
    return root


def test_sun3d_layout_pairs_depth_takes_newest_extrinsics_and_skips_corrupt_images(
        tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    root = _sun3d_folder(tmp_path / "seq")
    bad = sorted((root / "image").iterdir())[2]
    bad.write_bytes(b"\xff\xd8 this is not a jpeg")
    reader = open_sequence(root)
    with caplog.at_level(logging.WARNING):
        frames = list(reader)
    assert [f.index for f in frames] == [0, 1, 3]              # frame 2 skipped, run goes on
    assert reader.skipped == [str(bad)] and bad.name in caplog.text
    assert [float(f.depth[0, 0]) for f in frames] == pytest.approx([1.0, 1.1, 1.3])
    assert frames[0].pose[0, 3] == 1.0 and frames[2].pose is None  # newest file, 2 frames
    assert frames[1].stamp == pytest.approx(0.033)


def _tum_folder(root: Path, name: str = "rgbd_dataset_freiburg1_xyz") -> Path:
    seq = root / name
    (seq / "rgb").mkdir(parents=True)
    (seq / "depth").mkdir()
    rgb, depth = ["# color images", "# timestamp filename"], ["# depth maps"]
    for i in range(3):
        t = 100.0 + i / 30
        cv2.imwrite(str(seq / "rgb" / f"{t:.6f}.png"), _colour(i))
        cv2.imwrite(str(seq / "depth" / f"{t + 0.01:.6f}.png"),
                    np.full((24, 32), 5000 * (i + 1), np.uint16))
        rgb.append(f"{t:.6f} rgb/{t:.6f}.png")
        depth.append(f"{t + 0.01:.6f} depth/{t + 0.01:.6f}.png")
    rgb.append("200.000000 rgb/200.000000.png")               # no depth within 20 ms: dropped
    (seq / "rgb.txt").write_text("\n".join(rgb) + "\n")
    (seq / "depth.txt").write_text("\n".join(depth) + "\n")
    # 90° about z, at the first frame's time only
    (seq / "groundtruth.txt").write_text(
        "# timestamp tx ty tz qx qy qz qw\n100.000 1 2 3 0 0 0.7071068 0.7071068\n")
    return seq


def test_tum_layout_associates_by_timestamp_and_uses_the_sensor_calibration(
        tmp_path: Path) -> None:
    reader = open_sequence(_tum_folder(tmp_path))
    assert reader.kind == "tum" and len(reader) == 3
    assert reader.intrinsics[0, 0] == 517.3                    # freiburg1 from the folder name
    frames = list(reader)
    assert [float(f.depth[0, 0]) for f in frames] == pytest.approx([1.0, 2.0, 3.0])
    pose = frames[0].pose
    np.testing.assert_allclose(pose[:3, 3], [1, 2, 3])
    np.testing.assert_allclose(pose[:3, :3], [[0, -1, 0], [1, 0, 0], [0, 0, 1]], atol=1e-6)
    assert frames[1].pose is None


def test_missing_folders_and_intrinsics_are_clear_errors(tmp_path: Path) -> None:
    with pytest.raises(SequenceError, match="does not exist"):
        open_sequence(tmp_path / "nowhere")
    with pytest.raises(SequenceError, match="freiburg"):
        open_sequence(_tum_folder(tmp_path, name="my_tum_copy"))
    seven = tmp_path / "seven"
    seven.mkdir()
    cv2.imwrite(str(seven / "frame-000000.color.png"), _colour(0))
    with pytest.raises(SequenceError, match=r"camera-intrinsics\.txt"):
        open_sequence(seven)
    (tmp_path / "empty").mkdir()
    with pytest.raises(SequenceError, match="not a SUN3D"):
        open_sequence(tmp_path / "empty")
    with pytest.raises(SequenceError, match="no frame in"):
        open_sequence(_sun3d_folder(tmp_path / "sun"), start=10)
