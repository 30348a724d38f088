"""A synthetic RGB-D sequence for machines without a dataset: a textured world
(:mod:`twinslam.sequences.synthetic_worlds`: the room, the corridor) seen by a hand-held camera
on a smooth AR-like walk, ray-cast per pixel, so depth and ground-truth poses are exact.
Deterministic from a seed (the seed picks the walk, never the place).

World frame: x right, y down, z forward (the camera convention), origin at the world's centre.
"""

from __future__ import annotations

import hashlib
from collections.abc import Iterator
from dataclasses import dataclass, field
from functools import cache
from pathlib import Path

import numba
import numpy as np

from twinslam.kernel_cache import njit
from twinslam.sequences.decoded_frames import DecodedFrameCache, Frame
from twinslam.sequences.frame import RgbdFrame
from twinslam.sequences.synthetic_worlds import FPS, WORLDS, SyntheticWorld, spec_name


@dataclass
class SyntheticSequence:
    """``n_frames`` frames at 30 Hz of the ``world`` (a name of
    :data:`~twinslam.sequences.synthetic_worlds.WORLDS`); a
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
    world_name: str = "room"
    #: rendered frames kept on disk (:mod:`twinslam.sequences.decoded_frames`); None: every
    #: frame ray-cast as it is read
    cache: DecodedFrameCache | None = None

    def __post_init__(self) -> None:
        if self.n_frames < 1:
            raise ValueError("a synthetic sequence needs at least one frame")
        if self.world_name not in WORLDS:
            raise ValueError(f"unknown synthetic world {self.world_name!r}: one of "
                             f"{', '.join(WORLDS)}")
        self.world: SyntheticWorld = WORLDS[self.world_name]()
        self.intrinsics = np.array([[self.fx, 0, (self.width - 1) / 2],
                                    [0, self.fx, (self.height - 1) / 2], [0, 0, 1.0]])
        rng = np.random.default_rng(self.seed)
        self._phase = rng.uniform(0, 2 * np.pi, 6)
        self._textures = self.world.packed_textures()
        u, v = np.meshgrid(np.arange(self.width), np.arange(self.height))
        self._rays = np.stack([(u - self.intrinsics[0, 2]) / self.fx,
                               (v - self.intrinsics[1, 2]) / self.fx,
                               np.ones_like(u, dtype=np.float64)], axis=-1).reshape(-1, 3)

    def __len__(self) -> int:
        return self.n_frames - self.first

    def select(self, start: int, stop: int) -> SyntheticSequence:
        """Frames [start, stop) of the same world and walk."""
        return SyntheticSequence(stop, self.seed, self.width, self.height, self.fx, self.path,
                                 first=start, world_name=self.world_name, cache=self.cache)

    @property
    def stamps(self) -> np.ndarray:
        return np.arange(self.first, self.n_frames) / FPS

    @property
    def poses(self) -> list[np.ndarray]:
        return [self.pose(i) for i in range(self.first, self.n_frames)]

    def pose(self, i: int) -> np.ndarray:
        """Camera-to-world at frame i of the world's walk."""
        return self.world.walk(i / FPS, self._phase)

    def render(self, i: int) -> tuple[np.ndarray, np.ndarray]:
        """(RGB image, depth in metres, 0 past the sensor's range) of frame i, by ray casting
        against the world's faces."""
        pose = self.pose(i)
        color = np.empty((self.height, self.width, 3), dtype=np.uint8)
        depth = np.empty((self.height, self.width), dtype=np.float32)
        flat, offsets, widths, heights = self._textures
        _cast(self._rays, np.ascontiguousarray(pose[:3, :3]), np.ascontiguousarray(pose[:3, 3]),
              self.world.half, flat, offsets, widths, heights, self.world.texel_m,
              self.world.max_depth_m, color.reshape(-1, 3), depth.reshape(-1))
        return color, depth

    def __iter__(self) -> Iterator[RgbdFrame]:
        for i in range(len(self)):
            yield self.read(i)

    def read(self, i: int) -> RgbdFrame:
        """Frame ``i`` of the selection (rendered on demand, in any order; read back where the
        cache holds it)."""
        j = self.first + i
        pose = self.pose(j)
        made: Frame | None
        if self.cache is None:
            made = self.render(j)
        else:
            key = DecodedFrameCache.key([
                b"synthetic", _renderer(self.world_name),
                np.array([self.width, self.height, self.fx], dtype=np.float64).tobytes(),
                np.ascontiguousarray(pose, dtype=np.float64).tobytes()])
            made = self.cache.fetch(key, lambda: self.render(j))
        assert made is not None, "a ray cast always makes its frame"
        color, depth = made
        return RgbdFrame(i, j / FPS, color, depth, self.intrinsics, pose,
                         f"{spec_name(self.world_name)}-{j:06d}")


@cache
def _renderer(world_name: str) -> bytes:
    """A digest of what a frame of ``world_name`` is rendered from besides its camera and pose:
    this module's source (the ray cast), the world's box, textures and depth range, and the
    numerical libraries that compile and run the cast."""
    world = WORLDS[world_name]()
    digest = hashlib.sha256(Path(__file__).read_bytes())
    digest.update(f"numba {numba.__version__} numpy {np.__version__}".encode())
    digest.update(np.array([*world.half, world.texel_m, world.max_depth_m]).tobytes())
    for part in world.packed_textures():
        digest.update(np.ascontiguousarray(part).tobytes())
    return digest.digest()


@njit(cache=True)
def _cast(rays: np.ndarray, rot: np.ndarray, origin: np.ndarray, half: np.ndarray,
          texels: np.ndarray, offsets: np.ndarray, widths: np.ndarray, heights: np.ndarray,
          texel: float, max_depth: float, color: np.ndarray, depth: np.ndarray) -> None:
    """Per pixel: the nearest face the ray leaves the box through, its texel (a face's texture
    tiles), its depth (the rays have camera z = 1, so the ray parameter is the depth; 0 past
    ``max_depth``, as a depth sensor past its range)."""
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
        s_ax = 0 if axis == 2 else 2          # a texture's columns: along z but on the z faces
        t_ax = 0 if axis == 1 else 1          # its rows: along y but on the floor and ceiling
        hs = origin[s_ax] + d[s_ax] * best + half[s_ax]
        ht = origin[t_ax] + d[t_ax] * best + half[t_ax]
        su = int(hs / texel) % widths[face]
        sv = int(ht / texel) % heights[face]
        texel_index = offsets[face] + sv * widths[face] + su
        for c in range(3):
            color[p, c] = texels[texel_index, c]
        depth[p] = best if best <= max_depth else 0.0
