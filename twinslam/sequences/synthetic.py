"""A synthetic RGB-D sequence for machines without a dataset: a room whose walls, floor and
ceiling carry real photographs (scikit-image's bundled sample images), seen by a hand-held
camera on a smooth AR-like trajectory, ray-cast per pixel, so depth and ground-truth poses are
exact. Deterministic from a seed.

World frame: x right, y down, z forward (the camera convention), origin at the room's centre.
"""

from __future__ import annotations

import importlib.resources
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
from numba import njit

from twinslam.common.rotations import matrix_from_yaw_pitch_roll
from twinslam.sequences.frame import RgbdFrame

ROOM_HALF = np.array([3.0, 1.4, 2.5])      #: half extents (x, y, z) in metres
TEXEL_M = 0.004                             #: one texture pixel covers 4 mm
FPS = 30.0
TEX_SIZE = 512                              #: textures are resampled to this square size
#: texture of each face, in order -x, +x, -y (ceiling), +y (floor), -z, +z
FACE_IMAGES = ("brick.png", "coffee.png", "camera.png", "gravel.png", "astronaut.png",
               "chelsea.png")


def _texture(name: str) -> np.ndarray:
    path = importlib.resources.files("skimage.data") / name
    img = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if img is None:
        raise FileNotFoundError(f"scikit-image sample image {path} is missing")
    return cv2.cvtColor(img, cv2.COLOR_BGR2RGB)


@dataclass
class SyntheticSequence:
    """``n_frames`` frames at 30 Hz of the textured room; a
    :class:`~twinslam.sequences.frame.RandomAccessSequence`."""

    n_frames: int = 900
    seed: int = 0
    width: int = 640
    height: int = 480
    fx: float = 525.0
    path: Path = Path("synthetic")
    kind: str = "synthetic"
    skipped: list[str] = field(default_factory=list)
    first: int = 0                 #: frames [first, n_frames) are played (see select)

    def __post_init__(self) -> None:
        if self.n_frames < 1:
            raise ValueError("a synthetic sequence needs at least one frame")
        self.intrinsics = np.array([[self.fx, 0, (self.width - 1) / 2],
                                    [0, self.fx, (self.height - 1) / 2], [0, 0, 1.0]])
        rng = np.random.default_rng(self.seed)
        self._phase = rng.uniform(0, 2 * np.pi, 6)
        self._textures = np.stack([cv2.resize(_texture(n), (TEX_SIZE, TEX_SIZE),
                                              interpolation=cv2.INTER_AREA)
                                   for n in FACE_IMAGES])
        u, v = np.meshgrid(np.arange(self.width), np.arange(self.height))
        self._rays = np.stack([(u - self.intrinsics[0, 2]) / self.fx,
                               (v - self.intrinsics[1, 2]) / self.fx,
                               np.ones_like(u, dtype=np.float64)], axis=-1).reshape(-1, 3)

    def __len__(self) -> int:
        return self.n_frames - self.first

    def select(self, start: int, stop: int) -> SyntheticSequence:
        """Frames [start, stop) of the same room and trajectory."""
        return SyntheticSequence(stop, self.seed, self.width, self.height, self.fx, first=start)

    @property
    def stamps(self) -> np.ndarray:
        return np.arange(self.first, self.n_frames) / FPS

    @property
    def poses(self) -> list[np.ndarray]:
        return [self.pose(i) for i in range(self.first, self.n_frames)]

    def pose(self, i: int) -> np.ndarray:
        """Camera-to-world at frame i: a slow walk around the room's middle, looking around
        (yaw ±70°), with a hand's small pitch and roll."""
        t = i / FPS
        p = self._phase
        position = np.array([1.2 * np.sin(0.21 * t + p[0]), 0.15 * np.sin(0.53 * t + p[1]),
                             0.9 * np.sin(0.17 * t + p[2])])
        yaw = np.radians(70) * np.sin(0.25 * t + p[3])
        pitch = np.radians(8) * np.sin(0.41 * t + p[4])
        roll = np.radians(4) * np.sin(0.37 * t + p[5])
        pose = np.eye(4)
        pose[:3, :3] = matrix_from_yaw_pitch_roll(yaw, pitch, roll)
        pose[:3, 3] = position
        return pose

    def render(self, i: int) -> tuple[np.ndarray, np.ndarray]:
        """(RGB image, depth in metres) of frame i, by ray casting against the room's faces."""
        pose = self.pose(i)
        color = np.empty((self.height, self.width, 3), dtype=np.uint8)
        depth = np.empty((self.height, self.width), dtype=np.float32)
        _cast(self._rays, np.ascontiguousarray(pose[:3, :3]), np.ascontiguousarray(pose[:3, 3]),
              ROOM_HALF, self._textures, TEXEL_M, color.reshape(-1, 3), depth.reshape(-1))
        return color, depth

    def __iter__(self) -> Iterator[RgbdFrame]:
        for i in range(len(self)):
            yield self.read(i)

    def read(self, i: int) -> RgbdFrame:
        """Frame ``i`` of the selection (rendered on demand, in any order)."""
        j = self.first + i
        color, depth = self.render(j)
        return RgbdFrame(i, j / FPS, color, depth, self.intrinsics, self.pose(j),
                         f"synthetic-{j:06d}")


@njit(cache=True)
def _cast(rays: np.ndarray, rot: np.ndarray, origin: np.ndarray, half: np.ndarray,
          textures: np.ndarray, texel: float, color: np.ndarray, depth: np.ndarray) -> None:
    """Per pixel: the nearest wall the ray leaves the box through, its texel, its depth (the
    rays have camera z = 1, so the ray parameter is the depth)."""
    size = textures.shape[1]
    for p in range(rays.shape[0]):
        d0 = rot[0, 0] * rays[p, 0] + rot[0, 1] * rays[p, 1] + rot[0, 2] * rays[p, 2]
        d1 = rot[1, 0] * rays[p, 0] + rot[1, 1] * rays[p, 1] + rot[1, 2] * rays[p, 2]
        d2 = rot[2, 0] * rays[p, 0] + rot[2, 1] * rays[p, 1] + rot[2, 2] * rays[p, 2]
        d = (d0, d1, d2)
        best, axis = np.inf, 0
        for a in range(3):
            if d[a] != 0.0:
                bound = half[a] if d[a] > 0.0 else -half[a]
                t = (bound - origin[a]) / d[a]
                if 0.0 < t < best:
                    best, axis = t, a
        face = 2 * axis + (1 if d[axis] > 0.0 else 0)
        s_ax = 1 if axis == 0 else 0
        t_ax = 1 if axis == 2 else 2
        hs = origin[s_ax] + d[s_ax] * best + half[s_ax]
        ht = origin[t_ax] + d[t_ax] * best + half[t_ax]
        su = int(hs / texel) % size
        sv = int(ht / texel) % size
        for c in range(3):
            color[p, c] = textures[face, sv, su, c]
        depth[p] = best
