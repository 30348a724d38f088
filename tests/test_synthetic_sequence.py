"""The synthetic room: deterministic, exact depth and poses, and trackable by the front end."""

from __future__ import annotations

from collections.abc import Iterator

import cv2
import numpy as np
import pytest
from evo.core import metrics
from evo.core.trajectory import PosePath3D
from scipy.stats import spearmanr

from twinslam.sequences.frame import SequenceError
from twinslam.sequences.opening import open_sequence, synthetic_walk
from twinslam.sequences.synthetic import SyntheticSequence
from twinslam.sequences.synthetic_worlds import ROOM_HALF
from twinslam.simulator.extraction import extract_covisibility


def test_same_seed_same_frames_other_seed_other_trajectory() -> None:
    a, b, c = SyntheticSequence(5, seed=1), SyntheticSequence(5, seed=1), SyntheticSequence(
        5, seed=2)
    fa, fb, fc = list(a), list(b), list(c)
    assert all(np.array_equal(x.color, y.color) and np.array_equal(x.depth, y.depth)
               for x, y in zip(fa, fb, strict=True))
    assert not np.allclose(fa[3].pose, fc[3].pose)
    assert fa[1].stamp == pytest.approx(1 / 30) and fa[0].color.shape == (480, 640, 3)


def test_depth_and_pose_are_exact_every_pixel_lands_on_a_wall() -> None:
    seq = SyntheticSequence(60, seed=0)
    for frame in list(seq)[::20]:
        k, h, w = frame.intrinsics, *frame.depth.shape
        u, v = np.meshgrid(np.arange(w), np.arange(h))
        z = frame.depth.astype(np.float64)
        cam = np.stack([(u - k[0, 2]) * z / k[0, 0], (v - k[1, 2]) * z / k[1, 1], z], -1)
        world = cam.reshape(-1, 3) @ frame.pose[:3, :3].T + frame.pose[:3, 3]
        on_wall = np.max(np.abs(world) / ROOM_HALF, axis=1)
        np.testing.assert_allclose(on_wall, 1.0, atol=1e-5)     # float32 depth rounding


def test_open_sequence_understands_synthetic_with_frames_and_ranges() -> None:
    seq = open_sequence("synthetic:50", start=10, end=20)
    assert len(seq) == 10 and seq.kind == "synthetic"
    frames = list(seq)
    assert frames[0].index == 0 and frames[0].stamp == pytest.approx(10 / 30)
    with pytest.raises(SequenceError, match="synthetic"):
        open_sequence("synthetic:many")


def test_a_synthetic_spec_names_another_devices_focal_length() -> None:
    """``synthetic-corridor:frames:seed:focal``: the same walk seen by a camera of another
    focal length (another device's), the intrinsics it reports following; a walk of another
    seed keeps it; a focal no 640-pixel camera has is refused, naming the range."""
    wide = open_sequence("synthetic-corridor:3:1:420")
    default = open_sequence("synthetic-corridor:3:1")
    assert wide.intrinsics[0, 0] == wide.intrinsics[1, 1] == 420.0
    assert default.intrinsics[0, 0] == 525.0
    np.testing.assert_allclose(next(iter(wide)).pose, next(iter(default)).pose)
    assert synthetic_walk("synthetic-corridor:3:1:420", 5) == "synthetic-corridor:3:5:420"
    assert synthetic_walk("synthetic:40", 2) == "synthetic:40:2"
    with pytest.raises(SequenceError, match="200-2000 px"):
        open_sequence("synthetic:3:0:20")
    with pytest.raises(SequenceError, match=r"\[:focal\]"):
        open_sequence("synthetic:3:0:wide")


@pytest.fixture
def one_opencv_thread() -> Iterator[None]:
    """OpenCV on one thread for the test (its pool's threads would compete with the other
    workers'), and as many as before for the tests its worker runs next."""
    before = cv2.getNumThreads()
    cv2.setNumThreads(1)
    yield
    cv2.setNumThreads(before)


@pytest.mark.slow
@pytest.mark.usefixtures("one_opencv_thread")
def test_front_end_on_the_synthetic_room_tracks_and_sees_real_covisibility() -> None:
    """Exact ground truth, and what the 7-Scenes sample lacks: views 2 m and > 90° apart."""
    seq = open_sequence("synthetic:450")
    data, poses, report = extract_covisibility(seq)
    ref, est = PosePath3D(poses_se3=seq.poses), PosePath3D(poses_se3=list(poses))
    est.align(ref, correct_scale=False)
    ape = metrics.APE(metrics.PoseRelation.translation_part)
    ape.process_data((ref, est))
    ate = ape.get_statistic(metrics.StatisticsType.rmse)
    gt = np.array(seq.poses)
    i, j = np.triu_indices(len(gt), 1)
    dist = np.linalg.norm(gt[i, :3, 3] - gt[j, :3, 3], axis=1)
    angle = np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", gt[i, :3, 2], gt[j, :3, 2]),
                                         -1, 1)))
    w = data.weights(np.arange(len(gt)), np.arange(len(gt)))[i, j]
    far = (dist > 2.0) & (angle > 90)
    rho = spearmanr(w, dist).statistic
    print(f"\nsynthetic room, 450 frames: ATE {ate * 1000:.1f} mm, {report.untracked} "
          f"untracked; ρ(weight, centre distance) = {rho:.2f}; {far.sum()} pairs > 2 m and "
          f"> 90° apart share {w[far].mean():.2f} points (max {w[far].max():.0f}) of "
          f"{np.diff(data.point_offsets).mean():.0f} per frame")
    assert report.untracked == 0 and ate < 0.02
    # "almost none": under 1 % of a frame's points (two views 2 m apart can still both see a
    # corner of the room, so a few shared points are real)
    assert rho <= -0.5 and far.sum() > 100
    assert w[far].mean() < 0.01 * np.diff(data.point_offsets).mean()
