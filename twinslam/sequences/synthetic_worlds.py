"""The places the synthetic sequence renders, and how its camera walks through them.

Each world is an axis-aligned box whose six faces carry textures (any size each; a texture
tiles when its face is larger). Two are built in:

* ``room`` — a 6 x 2.8 x 5 m room whose faces carry six of scikit-image's photographs, tiled
  every 2 m, walked round its middle looking around. Every wall is in view from everywhere:
  a map of 15 keyframes covers it, so the map the edge keeps hardly matters (what the
  project's unit and node tests need: a camera that always tracks).
* ``corridor`` — a 2.4 x 2.6 x 24 m corridor walked out along its length and back, looking
  from wall to wall. Its walls are one long poster run that never repeats (panels cut at
  random from scikit-image's photographs, each scaled, turned, tinted and labelled its own
  way), and the depth sensor reads to ``max_depth_m`` (5 m, about a structured-light
  sensor's range): what the camera saw 5 m back is out of view, so the keyframes the edge evicted on
  the way out are what the way back needs — the world where map management decides
  tracking, as on a real revisit.

World frame: x right, y down, z forward (the camera convention), origin at the box's centre.
"""

from __future__ import annotations

import importlib.resources
from collections.abc import Callable
from dataclasses import dataclass
from functools import cache

import cv2
import numpy as np

from twinslam.rotations import matrix_from_yaw_pitch_roll

FPS = 30.0
#: a walk: (frame time in seconds, the seed's six phases) → 4×4 camera-to-world
Walk = Callable[[float, np.ndarray], np.ndarray]


@dataclass(frozen=True)
class SyntheticWorld:
    """A textured box and the walk through it."""

    name: str
    half: np.ndarray                   #: half extents (x, y, z), metres
    #: per face -x, +x, -y (ceiling), +y (floor), -z, +z: rows × columns × RGB, the columns
    #: along z on the walls along z, floor and ceiling (a long face's texture is read along
    #: its rows, which keeps a ray caster's reads near each other), along x on the end walls
    #: (z faces); the rows along y, but along x on the floor and ceiling
    textures: tuple[np.ndarray, ...]
    texel_m: float                     #: the side of one texture pixel on its face
    walk: Walk
    max_depth_m: float = np.inf        #: farther surfaces are seen but read depth 0

    def __post_init__(self) -> None:
        # cached by the world's factory: shared, so never written to (:func:`_read_only`)
        object.__setattr__(self, "half", _read_only(np.array(self.half, dtype=np.float64)))
        for texture in self.textures:
            _read_only(texture)

    def packed_textures(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The six textures as one flat RGB array, with each face's offset, width, height
        (what the ray caster indexes)."""
        flat = np.concatenate([t.reshape(-1, 3) for t in self.textures])
        sizes = np.array([t.shape[0] * t.shape[1] for t in self.textures], dtype=np.int64)
        offsets = np.concatenate([[0], np.cumsum(sizes)[:-1]]).astype(np.int64)
        widths = np.array([t.shape[1] for t in self.textures], dtype=np.int64)
        heights = np.array([t.shape[0] for t in self.textures], dtype=np.int64)
        return np.ascontiguousarray(flat), offsets, widths, heights


@cache
def photograph(name: str) -> np.ndarray:
    """One of scikit-image's bundled sample images, RGB uint8 (a grey one as three equal
    channels); read once a process, never written to."""
    path = importlib.resources.files("skimage.data") / name
    img = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if img is None:
        raise FileNotFoundError(f"scikit-image sample image {path} is missing")
    return _read_only(cv2.cvtColor(img, cv2.COLOR_BGR2RGB))


def _read_only(a: np.ndarray) -> np.ndarray:
    """``a``, made unwritable: a cached world is shared by everything a process renders, and
    one write into it would change every later frame of every sequence of that world."""
    a.setflags(write=False)
    return a


def _pose(position: np.ndarray, yaw: float, pitch: float, roll: float) -> np.ndarray:
    pose = np.eye(4)
    pose[:3, :3] = matrix_from_yaw_pitch_roll(yaw, pitch, roll)
    pose[:3, 3] = position
    return pose


# --- the room ---------------------------------------------------------------------------------

ROOM_HALF = np.array([3.0, 1.4, 2.5])
ROOM_TEXTURE_SIZE = 512                  #: each photograph resampled to this square
ROOM_IMAGES = ("brick.png", "coffee.png", "camera.png", "gravel.png", "astronaut.png",
               "chelsea.png")


def room_walk(t: float, p: np.ndarray) -> np.ndarray:
    """A slow walk around the room's middle, looking around (yaw ±70°), with a hand's small
    pitch and roll."""
    position = np.array([1.2 * np.sin(0.21 * t + p[0]), 0.15 * np.sin(0.53 * t + p[1]),
                         0.9 * np.sin(0.17 * t + p[2])])
    return _pose(position, np.radians(70) * np.sin(0.25 * t + p[3]),
                 np.radians(8) * np.sin(0.41 * t + p[4]), np.radians(4) * np.sin(0.37 * t + p[5]))


@cache
def room() -> SyntheticWorld:
    square = [cv2.resize(photograph(n), (ROOM_TEXTURE_SIZE, ROOM_TEXTURE_SIZE),
                         interpolation=cv2.INTER_AREA) for n in ROOM_IMAGES]
    # the walls along z, the floor and the ceiling show their photographs transposed, as the
    # room always has
    textures = tuple(np.ascontiguousarray(t.transpose(1, 0, 2)) if face < 4 else t
                     for face, t in enumerate(square))
    return SyntheticWorld("room", ROOM_HALF, textures, 0.004, room_walk)


# --- the corridor -----------------------------------------------------------------------------

CORRIDOR_HALF = np.array([1.2, 1.3, 12.0])
CORRIDOR_TEXEL_M = 0.005
CORRIDOR_MAX_DEPTH_M = 5.0
#: the photographs the corridor's panels are cut from
#: (the detailed ones: a smooth gradient or a blurred photograph is a blank wall to ORB)
PANEL_SOURCES = ("astronaut.png", "chelsea.png", "coffee.png", "rocket.jpg",
                 "hubble_deep_field.jpg", "ihc.png", "motorcycle_left.png", "camera.png",
                 "coins.png", "text.png", "brick.png", "grass.png", "gravel.png")
PANEL_M = (0.5, 1.1)                     #: a panel's width, metres (drawn per panel)
WALK_SPEED_M_S = 0.5
TURN_S = 3.0                             #: turning round at an end, standing
END_MARGIN_M = 1.5                       #: how far from an end wall the walk turns
LOOK_AROUND = np.radians(75)             #: yaw swing either side of the walking direction
GAZE_SHARPNESS = 2.0                     #: how much of the swing the gaze spends on a wall
#: the fixed seed of the corridor's posters: the place is the same for every walk
POSTER_SEED = 2024


def poster_run(width_px: int, height_px: int, rng: np.random.Generator) -> np.ndarray:
    """A face covered left to right by panels, each a random crop of a random photograph,
    scaled to the panel, turned by a multiple of 90°, mirrored or not, tinted, and labelled
    with a random code: no two places of the run look alike."""
    sources = [photograph(n) for n in PANEL_SOURCES]
    face = np.empty((height_px, width_px, 3), dtype=np.uint8)
    x = 0
    while x < width_px:
        w = min(width_px - x, int(rng.uniform(*PANEL_M) / CORRIDOR_TEXEL_M))
        src = sources[rng.integers(len(sources))]
        h_src, w_src = src.shape[:2]
        frac = rng.uniform(0.35, 0.9)
        ch, cw = max(8, int(h_src * frac)), max(8, int(w_src * frac))
        y0, x0 = int(rng.integers(0, h_src - ch + 1)), int(rng.integers(0, w_src - cw + 1))
        crop = np.rot90(src[y0:y0 + ch, x0:x0 + cw], int(rng.integers(4)))
        if rng.random() < 0.5:
            crop = crop[:, ::-1]
        panel = cv2.resize(np.ascontiguousarray(crop), (w, height_px),
                           interpolation=cv2.INTER_AREA)
        tint = rng.uniform(0.6, 1.3, 3)
        panel = np.clip(panel.astype(np.float32) * tint, 0, 255).astype(np.uint8)
        for _ in range(int(rng.integers(1, 4))):
            label = "".join(chr(int(c)) for c in rng.integers(65, 91, 2)) + str(
                int(rng.integers(10, 1000)))
            org = (int(rng.integers(0, max(1, w - 120))), int(rng.integers(40, height_px)))
            colour = tuple(int(c) for c in rng.integers(0, 256, 3))
            cv2.putText(panel, label, org, cv2.FONT_HERSHEY_SIMPLEX, rng.uniform(1.0, 2.5),
                        colour, int(rng.integers(2, 6)), cv2.LINE_AA)
        face[:, x:x + w] = panel
        x += w
    return face


def corridor_walk(t: float, p: np.ndarray) -> np.ndarray:
    """Out along the corridor (+z) at walking pace, turning round standing at the far end,
    back, and so on; the gaze goes from wall to wall (yaw ±75° about the walking direction,
    a visitor looking at the posters) with a hand's small pitch, roll and sway."""
    span = 2 * (CORRIDOR_HALF[2] - END_MARGIN_M)
    leg_s = span / WALK_SPEED_M_S + TURN_S
    leg, into = divmod(t, leg_s)
    outward = int(leg) % 2 == 0
    walked = min(into, span / WALK_SPEED_M_S) * WALK_SPEED_M_S
    turning = max(0.0, into - span / WALK_SPEED_M_S) / TURN_S       # 0..1 at the leg's end
    start = -CORRIDOR_HALF[2] + END_MARGIN_M
    z = start + walked if outward else start + span - walked
    heading = (0.0 if outward else np.pi) + np.pi * (3 * turning**2 - 2 * turning**3)
    position = np.array([0.3 * np.sin(0.31 * t + p[0]), -0.1 + 0.05 * np.sin(0.53 * t + p[1]),
                         z])
    # most of the time on a wall, crossing the corridor's axis in about a second
    yaw = heading + LOOK_AROUND * np.tanh(GAZE_SHARPNESS * np.sin(0.35 * t + p[3])) / np.tanh(
        GAZE_SHARPNESS)
    return _pose(position, yaw, np.radians(6) * np.sin(0.41 * t + p[4]),
                 np.radians(3) * np.sin(0.37 * t + p[5]))


@cache
def corridor() -> SyntheticWorld:
    rng = np.random.default_rng(POSTER_SEED)
    hx, hy, hz = (CORRIDOR_HALF / CORRIDOR_TEXEL_M).astype(int)
    # (rows, columns) of each face's texture (SyntheticWorld.textures)
    shapes = ((2 * hy, 2 * hz),) * 2 + ((2 * hx, 2 * hz),) * 2 + ((2 * hy, 2 * hx),) * 2
    textures = tuple(poster_run(cols, rows, rng) for rows, cols in shapes)
    return SyntheticWorld("corridor", CORRIDOR_HALF, textures, CORRIDOR_TEXEL_M, corridor_walk,
                          CORRIDOR_MAX_DEPTH_M)


#: the worlds by name
WORLDS: dict[str, Callable[[], SyntheticWorld]] = {"room": room, "corridor": corridor}


def spec_name(world: str) -> str:
    """How a sequence spec (``open_sequence``) names a world: ``synthetic`` is the room (the
    first world, kept as it always was), ``synthetic-corridor`` the corridor."""
    return "synthetic" if world == "room" else f"synthetic-{world}"


#: the world of each sequence spec name
SPECS = {spec_name(w): w for w in WORLDS}
