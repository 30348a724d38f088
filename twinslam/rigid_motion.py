"""Rigid motions as twists: the logarithm and exponential of SE(3) in closed form.

The edge extrapolates every device's camera a slot ahead each slot (where it will look next:
the restores' headings, the ``mpc`` planner's frames) by spreading the slot's motion evenly
over its frames — the matrix logarithm of the relative pose, scaled, exponentiated.
``scipy.linalg.logm``/``expm`` on a 4×4 cost ~1.5 ms a slot; the closed forms (the rotation's
angle and axis from its quaternion, robust up to a half turn, and the left Jacobian for the
translation) give the same matrices in microseconds.

A twist is ``(ω, ρ)``: the rotation vector ω (axis × angle, radians) and ρ = V(ω)⁻¹ t, so
that ``pose_of(twist_of(T)) == T`` and ``twist_of(T) * s`` is the motion spread to a share s.
"""

from __future__ import annotations

import math

import numpy as np

from twinslam.rotations import quaternions_from_matrices

#: below this angle (radians) the series of the coefficients replace their closed forms,
#: which lose digits to cancellation near zero (1 − cos θ); the series' next terms are below
#: 1e-16 there
SMALL_ANGLE = 1e-2


def _hat(w: np.ndarray) -> np.ndarray:
    """The cross-product matrix [w]× of a 3-vector."""
    return np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])


def twist_of(pose: np.ndarray) -> np.ndarray:
    """The principal logarithm of a 4×4 rigid transform as a 6-vector (ω, ρ): the rotation
    vector from the rotation's unit quaternion (its shorter way round), ρ from the inverse
    left Jacobian. A half turn exactly has two logarithms; either is returned."""
    pose = np.asarray(pose, dtype=np.float64)
    x, y, z, w = quaternions_from_matrices(pose[:3, :3][None])[0]
    sin_half = math.sqrt(x * x + y * y + z * z)
    theta = 2.0 * math.atan2(sin_half, w)          # w ≥ 0 for the largest component's sign…
    if theta > math.pi:                            # …not always: take the shorter way
        theta -= 2.0 * math.pi
    axis = np.array([x, y, z]) / sin_half if sin_half > 0.0 else np.zeros(3)
    omega = axis * theta
    k = _hat(omega)
    if abs(theta) < SMALL_ANGLE:
        t2 = theta * theta
        c = 1.0 / 12.0 + t2 / 720.0 + t2 * t2 / 30240.0
    else:
        c = (1.0 - theta * math.sin(theta) / (2.0 * (1.0 - math.cos(theta)))) / (theta * theta)
    v_inv = np.eye(3) - 0.5 * k + c * (k @ k)
    return np.concatenate([omega, v_inv @ pose[:3, 3]])


def pose_of(twist: np.ndarray) -> np.ndarray:
    """The 4×4 rigid transform of a twist (ω, ρ): Rodrigues' rotation and V(ω) ρ."""
    twist = np.asarray(twist, dtype=np.float64).reshape(6)
    omega, rho = twist[:3], twist[3:]
    theta = float(np.linalg.norm(omega))
    k = _hat(omega)
    if theta < SMALL_ANGLE:
        t2 = theta * theta
        a = 1.0 - t2 / 6.0 + t2 * t2 / 120.0
        b = 0.5 - t2 / 24.0 + t2 * t2 / 720.0
        c = 1.0 / 6.0 - t2 / 120.0 + t2 * t2 / 5040.0
    else:
        a = math.sin(theta) / theta
        b = (1.0 - math.cos(theta)) / (theta * theta)
        c = (theta - math.sin(theta)) / (theta ** 3)
    kk = k @ k
    out = np.eye(4)
    out[:3, :3] = np.eye(3) + a * k + b * kk
    out[:3, 3] = (np.eye(3) + b * k + c * kk) @ rho
    return out
