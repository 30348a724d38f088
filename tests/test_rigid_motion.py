"""Rigid motions as twists: SE(3)'s logarithm and exponential in closed form, as SciPy's
matrix logarithm and exponential give them, at every angle a camera turns by in a slot."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.linalg import expm, logm
from scipy.spatial.transform import Rotation

from twinslam.rigid_motion import pose_of, twist_of


def _se3(twist: np.ndarray) -> np.ndarray:
    """The 4×4 Lie-algebra matrix of a twist (ω, ρ)."""
    w, rho = twist[:3], twist[3:]
    out = np.zeros((4, 4))
    out[:3, :3] = [[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]]
    out[:3, 3] = rho
    return out


@pytest.mark.parametrize("angle", [0.0, 1e-9, 1e-5, 9e-3, 1.1e-2, 0.3, 1.5, 3.0, 3.14])
def test_a_twist_is_the_matrix_logarithm_and_comes_back_by_the_exponential(angle: float) -> None:
    rng = np.random.default_rng(int(angle * 1e4) + 1)
    for _ in range(20):
        axis = rng.normal(size=3)
        pose = np.eye(4)
        pose[:3, :3] = Rotation.from_rotvec(axis / np.linalg.norm(axis) * angle).as_matrix()
        pose[:3, 3] = rng.normal(size=3)
        twist = twist_of(pose)
        np.testing.assert_allclose(_se3(twist), np.real(logm(pose)), atol=1e-10)
        np.testing.assert_allclose(pose_of(twist), pose, atol=1e-10)
        share = rng.uniform(-3.0, 3.0)
        np.testing.assert_allclose(pose_of(twist * share), np.real(expm(_se3(twist) * share)),
                                   atol=1e-10)
