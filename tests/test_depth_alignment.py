"""A pose from 3D–3D matches: the closed form finds a known rigid motion, the fit started at
an imperfect pose keeps the matches that agree in depth and leaves the ones that do not, and
the keypoints lifted into the camera by their depths project back where they were seen."""

from __future__ import annotations

import math

import numpy as np
import pytest

from twinslam.rotations import rotation_angle_deg
from twinslam.slam.back_end.depth_alignment import align_with_depth, rigid_fit
from twinslam.slam.projection_matching import back_project


def _pose(yaw_deg: float, pitch_deg: float, t: tuple[float, float, float]) -> np.ndarray:
    a, b = math.radians(yaw_deg), math.radians(pitch_deg)
    yaw = np.array([[math.cos(a), 0, math.sin(a)], [0, 1, 0], [-math.sin(a), 0, math.cos(a)]])
    pitch = np.array([[1, 0, 0], [0, math.cos(b), -math.sin(b)], [0, math.sin(b), math.cos(b)]])
    pose = np.eye(4)
    pose[:3, :3], pose[:3, 3] = yaw @ pitch, t
    return pose


def _wall(n: int, rng: np.random.Generator) -> np.ndarray:
    """``n`` points on one wall 2 m in front of the camera (the case PnP finds ambiguous)."""
    return np.column_stack([rng.uniform(-1.5, 1.5, n), rng.uniform(-1.0, 1.0, n),
                            np.full(n, 2.0) + rng.normal(0, 0.002, n)])


def test_the_closed_form_finds_a_known_rigid_motion() -> None:
    rng = np.random.default_rng(0)
    source = _wall(50, rng)
    motion = _pose(20.0, -7.0, (0.3, -0.1, 1.2))
    target = source @ motion[:3, :3].T + motion[:3, 3]
    np.testing.assert_allclose(rigid_fit(source, target), motion, atol=1e-9)
    with pytest.raises(ValueError, match="≥ 3"):
        rigid_fit(source[:2], target[:2])


def test_the_fit_from_a_poor_start_keeps_the_matches_that_agree_in_depth() -> None:
    """PnP's pose 2° and 5 cm off, a third of the matches wrong: the fit lands within a
    millimetre and a hundredth of a degree, counting only the right matches."""
    rng = np.random.default_rng(1)
    camera = _wall(300, rng)
    pose = _pose(3.0, 1.0, (0.5, 0.0, -1.0))
    world = camera @ pose[:3, :3].T + pose[:3, 3]
    wrong = rng.choice(300, 100, replace=False)
    world[wrong] += rng.uniform(0.3, 1.0, (100, 3))
    start = _pose(5.0, 1.0, (0.55, 0.0, -1.0))
    fitted = align_with_depth(start, camera, world, min_inliers=50)
    assert fitted.pose is not None and fitted.inliers == 200
    off = np.linalg.inv(pose) @ fitted.pose
    assert np.linalg.norm(off[:3, 3]) < 1e-3
    assert rotation_angle_deg(off[:3, :3]) < 0.01
    assert fitted.rms_m < 0.005
    # too few agree: no pose, and how many did
    few = align_with_depth(start, camera[:40], world[:40], min_inliers=50)
    assert few.pose is None and few.inliers <= 40


def test_lifted_pixels_project_back_where_they_were() -> None:
    k = np.array([[525.0, 0, 320], [0, 525.0, 240], [0, 0, 1]])
    xy = np.array([[10.0, 20.0], [320.0, 240.0], [600.0, 400.0]])
    points = back_project(xy, np.array([1.0, 2.5, 4.0]), k, np.eye(4))
    projected = points @ k.T
    np.testing.assert_allclose(projected[:, :2] / projected[:, 2:], xy)
    np.testing.assert_allclose(points[:, 2], [1.0, 2.5, 4.0])
