"""Rotation matrices ↔ quaternions (ROS order x, y, z, w) in plain NumPy.

Every node converts a pose per frame, and importing ``scipy.spatial`` for it cost each node
process ~0.3 s at start (measured with ``python -X importtime``); these few lines give the
same numbers as SciPy's ``Rotation`` (Markley's method, the same choice of sign).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np


def quaternion_from_matrix(rotation: np.ndarray) -> np.ndarray:
    """The unit quaternion (x, y, z, w) of a 3×3 rotation, by Markley's method: the largest
    of the trace and the diagonal picks the well-conditioned formula, and that component comes
    out positive. A slightly non-orthonormal matrix (a float32 dataset pose) is first replaced
    by the nearest orthonormal one (U Vᵀ of its SVD), as SciPy's ``Rotation.from_matrix`` does."""
    one: np.ndarray = quaternions_from_matrices(np.asarray(rotation).reshape(1, 3, 3))[0]
    return one


def quaternions_from_matrices(rotations: np.ndarray) -> np.ndarray:
    """:func:`quaternion_from_matrix` of each of ``(n, 3, 3)`` rotations at once, ``(n, 4)``:
    the edge converts every kept keyframe's pose for each device's map update and viewer
    messages every slot, and one SVD and one formula a pose in Python cost ~25 µs each."""
    stack = np.asarray(rotations, dtype=np.float64).reshape(-1, 3, 3)
    u, _, vt = np.linalg.svd(stack)
    r = u @ vt
    diagonal = np.diagonal(r, axis1=1, axis2=2)
    trace = diagonal.sum(axis=1)
    choice = np.argmax(np.column_stack([diagonal, trace]), axis=1)
    q = np.empty((len(r), 4))
    by_trace = choice == 3
    t = r[by_trace]
    q[by_trace] = np.column_stack([t[:, 2, 1] - t[:, 1, 2], t[:, 0, 2] - t[:, 2, 0],
                                   t[:, 1, 0] - t[:, 0, 1], 1.0 + trace[by_trace]])
    for i in range(3):                   # the largest diagonal entry is component i
        j, k = (i + 1) % 3, (i + 2) % 3
        pick = choice == i
        t = r[pick]
        q[pick, i] = 1.0 - trace[pick] + 2.0 * t[:, i, i]
        q[pick, j] = t[:, j, i] + t[:, i, j]
        q[pick, k] = t[:, k, i] + t[:, i, k]
        q[pick, 3] = t[:, k, j] - t[:, j, k]
    unit: np.ndarray = q / np.linalg.norm(q, axis=1, keepdims=True)
    return unit


def matrix_from_quaternion(quaternion_xyzw: Sequence[float] | np.ndarray) -> np.ndarray:
    """The 3×3 rotation of a quaternion (x, y, z, w), normalised first; ValueError for a zero
    quaternion, which is no rotation."""
    q = np.asarray(quaternion_xyzw, dtype=np.float64)
    norm = float(np.linalg.norm(q))
    if q.shape != (4,) or not np.isfinite(norm) or norm == 0.0:
        raise ValueError(f"not a rotation quaternion: {q.tolist()}")
    x, y, z, w = q / norm
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def matrix_from_yaw_pitch_roll(yaw: float, pitch: float, roll: float) -> np.ndarray:
    """Yaw about y, then pitch about x, then roll about z, each about the fixed axes
    (SciPy's extrinsic ``"yxz"``): R = R_z(roll) · R_x(pitch) · R_y(yaw)."""
    cy, sy, cp, sp, cr, sr = (np.cos(yaw), np.sin(yaw), np.cos(pitch), np.sin(pitch),
                              np.cos(roll), np.sin(roll))
    r_y = np.array([[cy, 0.0, sy], [0.0, 1.0, 0.0], [-sy, 0.0, cy]])
    r_x = np.array([[1.0, 0.0, 0.0], [0.0, cp, -sp], [0.0, sp, cp]])
    r_z = np.array([[cr, -sr, 0.0], [sr, cr, 0.0], [0.0, 0.0, 1.0]])
    rotation: np.ndarray = r_z @ r_x @ r_y
    return rotation


def rotation_angle_deg(rotation: np.ndarray) -> float:
    """The angle (degrees, 0–180) a 3×3 rotation turns about its axis, from the trace of the
    nearest orthonormal matrix (U Vᵀ of its SVD): a dataset's slightly non-orthonormal poses
    (7-Scenes' KinectFusion ones) read 0.8° too much a frame from the raw trace."""
    r = np.asarray(rotation, dtype=np.float64)
    if not np.isfinite(r).all():
        return float("nan")
    u, _, vt = np.linalg.svd(r)
    cos = (float(np.trace(u @ vt)) - 1.0) / 2.0
    return float(np.degrees(np.arccos(min(1.0, max(-1.0, cos)))))
