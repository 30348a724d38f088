"""Covisibility from a small geometric model: points on the walls of a room, a moving camera.

This is a *model*, not data: it exists so that tests and the demo have covisibility with the
right structure (nearby viewpoints share points, distant ones do not) on a machine without a
dataset. Experiments and figures use covisibility extracted from real frames.
"""

from __future__ import annotations

import numpy as np

from twinslam.covisibility.dataset import CovisibilityDataset


def room_points(rng: np.random.Generator, n_points: int, size: float = 6.0,
                height: float = 2.5) -> np.ndarray:
    """Points spread uniformly over the four walls of a size x size x height room."""
    wall = rng.integers(0, 4, n_points)
    u = rng.uniform(-size / 2, size / 2, n_points)
    z = rng.uniform(0.0, height, n_points)
    x = np.where(wall == 0, -size / 2, np.where(wall == 1, size / 2, u))
    y = np.where(wall == 2, -size / 2, np.where(wall == 3, size / 2, u))
    return np.stack([x, y, z], axis=1)


def walk(rng: np.random.Generator, n_frames: int, size: float = 6.0,
         turn_rate: float = 0.02) -> tuple[np.ndarray, np.ndarray]:
    """A smooth hand-held walk: positions (n, 3) and yaw angles (n,) inside the room."""
    pos = np.zeros((n_frames, 3))
    yaw = np.zeros(n_frames)
    p = np.array([0.0, 0.0, 1.5])
    heading, omega = rng.uniform(0, 2 * np.pi), 0.0
    for i in range(n_frames):
        omega = 0.95 * omega + rng.normal(0.0, turn_rate)
        heading += omega
        step = 0.01 * np.array([np.cos(heading), np.sin(heading), 0.0])
        if np.any(np.abs((p + step)[:2]) > size / 2 - 1.0):
            heading += np.pi / 2
            step = -step
        p = p + step
        pos[i], yaw[i] = p, heading
    return pos, yaw


def geometric_covisibility(n_frames: int = 600, n_points: int = 4000, seed: int = 0,
                           fov_deg: float = 60.0, max_range: float = 5.0) -> CovisibilityDataset:
    """Frames see the points inside their horizontal field of view and range."""
    rng = np.random.default_rng(seed)
    pts = room_points(rng, n_points)
    pos, yaw = walk(rng, n_frames)
    half = np.deg2rad(fov_deg) / 2
    sets = []
    for p, h in zip(pos, yaw, strict=True):
        d = pts - p
        dist = np.linalg.norm(d[:, :2], axis=1)
        bearing = np.arctan2(d[:, 1], d[:, 0]) - h
        bearing = (bearing + np.pi) % (2 * np.pi) - np.pi
        visible = (np.abs(bearing) < half) & (dist < max_range)
        sets.append(np.flatnonzero(visible))
    poses = np.concatenate([pos, np.zeros((n_frames, 2)), np.sin(yaw / 2)[:, None],
                            np.cos(yaw / 2)[:, None]], axis=1)
    return CovisibilityDataset.from_sets(sets, stamps=np.arange(n_frames) / 30.0, poses=poses,
                                         source=f"geometric room model, seed {seed}")
