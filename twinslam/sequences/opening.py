"""One entry point for every sequence source: a path or spec in, a :class:`Sequence` out."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from twinslam.sequences.decoded_frames import DecodedFrameCache
from twinslam.sequences.folders import (
    SEVEN_SCENES_COLOUR_INTRINSICS,
    SEVEN_SCENES_DEPTH_INTRINSICS,
    FolderSequence,
    read_matrix,
    read_seven_scenes,
    read_sun3d,
    read_tum,
)
from twinslam.sequences.frame import Sequence, SequenceError

if TYPE_CHECKING:
    from twinslam.sequences.synthetic import SyntheticSequence

#: frames of ``synthetic`` when the spec names no count
SYNTHETIC_DEFAULT_FRAMES = 900
#: the synthetic camera's focal length (px) when the spec names none (a Kinect-like 525)
DEFAULT_FOCAL_PX = 525.0
#: focal lengths a synthetic spec may name (px): about 115° to 18° across 640 px
MIN_FOCAL_PX, MAX_FOCAL_PX = 200.0, 2000.0
#: ``colour_intrinsics`` that sees each dataset through its colour camera: a 7-Scenes folder
#: whose intrinsics file is the dataset's depth camera's (585 px) through
#: :data:`~twinslam.sequences.folders.SEVEN_SCENES_COLOUR_INTRINSICS`, anything else — another
#: dataset, a 7-Scenes-like folder with a camera of its own — as it is
AUTO = "auto"


def open_sequence(path: str | Path, start: int = 0, end: int = -1,
                  colour_intrinsics: np.ndarray | str | Path | None = None,
                  depth_to_colour: np.ndarray | None = None,
                  frame_cache: DecodedFrameCache | None = None) -> Sequence:
    """Detect the layout of ``path`` and open frames [start, end) of it (end < 0: to the end):
    a dataset folder, a rosbag2 folder or ``.mcap`` file recorded by ``twinslam record``, or
    ``synthetic[:frames[:seed[:focal]]]`` (the rendered room) or
    ``synthetic-corridor[:frames[:seed[:focal]]]`` (the corridor walked out and back, where
    the edge's map decides tracking; the seed picks the walk, ``focal`` the camera's focal
    length in pixels: another device's camera). ``colour_intrinsics``: a dataset folder
    whose intrinsics file is its depth camera's (7-Scenes) is seen by a colour camera with
    these (a 3×3 matrix or the file of one), its depth registered to it, the colour camera
    at ``depth_to_colour`` (4×4) from the depth camera (None: the same place); None or "":
    the folder's own intrinsics; ``"auto"`` (:data:`AUTO`): a 7-Scenes scene's colour
    camera, any other source as it is.
    ``frame_cache``: a dataset folder's frames decoded, or a synthetic world's rendered, once
    and read back from there (what a reader that plays the frames again and again wants; a bag
    ignores it)."""
    if isinstance(colour_intrinsics, str) and colour_intrinsics == AUTO:
        sequence = _open(path, start, end, frame_cache)
        if (isinstance(sequence, FolderSequence) and sequence.kind == "7scenes"
                and np.allclose(sequence.intrinsics, SEVEN_SCENES_DEPTH_INTRINSICS)):
            return sequence.with_colour_camera(SEVEN_SCENES_COLOUR_INTRINSICS, depth_to_colour)
        return sequence
    if isinstance(colour_intrinsics, (str, Path)):
        colour_intrinsics = (read_matrix(Path(colour_intrinsics), 3, 3)
                             if str(colour_intrinsics) else None)
    if colour_intrinsics is None and depth_to_colour is not None:
        raise SequenceError("a depth-to-colour transform needs the colour camera's intrinsics")
    sequence = _open(path, start, end, frame_cache)
    if colour_intrinsics is None:
        return sequence
    if not isinstance(sequence, FolderSequence):
        raise SequenceError(f"{path}: colour intrinsics apply to a dataset folder's raw depth; "
                            "a synthetic world or a recorded bag is registered already")
    return sequence.with_colour_camera(colour_intrinsics, depth_to_colour)


def _open(path: str | Path, start: int, end: int, frame_cache: DecodedFrameCache | None
          ) -> Sequence:
    """The sequence ``path`` names, by its layout (:func:`open_sequence`)."""
    if str(path).startswith("synthetic"):
        # a misspelt world is refused with the worlds' names, never read as a folder
        return _open_synthetic(str(path), start, end, frame_cache)
    root = Path(path)
    if root.suffix == ".mcap" or (root / "metadata.yaml").is_file():
        # imported here: reading a bag loads rclpy and rosbags, which a folder never needs
        from twinslam.sequences.bag import open_bag

        return open_bag(root, start, end)
    return open_folder(root, start, end, frame_cache)


def is_synthetic(spec: str | Path) -> bool:
    """Whether ``spec`` names a rendered world (``synthetic[:…]``, ``synthetic-corridor[:…]``)
    rather than a path."""
    from twinslam.sequences.synthetic_worlds import SPECS

    return str(spec).partition(":")[0] in SPECS


def synthetic_walk(spec: str, seed: int, frames: int | None = None) -> str:
    """The spec of the same synthetic world walked by ``seed``: its frame count kept, or
    ``frames`` where it names none (the world's default without either), and its camera's
    focal length kept where it names one."""
    name, _, rest = spec.partition(":")
    count, _, rest = rest.partition(":")
    count = count or (str(frames) if frames else str(SYNTHETIC_DEFAULT_FRAMES))
    focal = rest.partition(":")[2]
    return f"{name}:{count}:{seed}" + (f":{focal}" if focal else "")


def focal_lengths(text: str) -> tuple[float, ...]:
    """Focal lengths in pixels separated by commas (``"525,450"``; ``""``: none), one a
    device; ValueError naming the text for anything else."""
    if not text.strip():
        return ()
    try:
        return tuple(float(f) for f in text.split(","))
    except ValueError:
        raise ValueError(f"focal lengths in pixels separated by commas (e.g. 525,450), not "
                         f"{text!r}") from None


def with_focal(spec: str, focal_px: float | None) -> str:
    """A synthetic walk's spec (``name[:frames[:seed[:focal]]]``) seen by a camera of focal
    length ``focal_px`` instead (None: as it is); ValueError for a spec of no synthetic
    world (a dataset's camera is the one that recorded it)."""
    if focal_px is None:
        return spec
    if not is_synthetic(spec):
        raise ValueError(f"a focal length goes with a synthetic world's walk, not {spec!r}")
    name, _, rest = spec.partition(":")
    frames, _, rest = rest.partition(":")
    seed = rest.partition(":")[0]
    return f"{name}:{frames}:{seed}:{focal_px:g}"


def _open_synthetic(spec: str, start: int, end: int, frame_cache: DecodedFrameCache | None
                    ) -> SyntheticSequence:
    from twinslam.sequences.synthetic_worlds import SPECS

    name, _, rest = spec.partition(":")
    frames, _, rest = rest.partition(":")
    seed, _, focal = rest.partition(":")
    if name not in SPECS:
        raise SequenceError(f"unknown synthetic world {name!r}: one of {', '.join(SPECS)}")
    try:
        n = int(frames) if frames else SYNTHETIC_DEFAULT_FRAMES
        walk = int(seed) if seed else 0
        fx = float(focal) if focal else DEFAULT_FOCAL_PX
    except ValueError:
        raise SequenceError(f"{name}[:frames[:seed[:focal]]] expected, got {spec!r}") from None
    if not MIN_FOCAL_PX <= fx <= MAX_FOCAL_PX:
        raise SequenceError(f"{spec}: a focal length of {MIN_FOCAL_PX:.0f}-{MAX_FOCAL_PX:.0f} "
                            f"px for the synthetic camera's 640x480 images, not {fx:g}")
    stop = n if end < 0 else min(end, n)
    if not 0 <= start < stop:
        raise SequenceError(f"{spec}: bad frame range start={start} end={end}")
    # imported here: the renderer loads numba (0.4-0.5 s a process), which a player of a
    # dataset folder never needs
    from twinslam.sequences.synthetic import SyntheticSequence

    return SyntheticSequence(n_frames=n, seed=walk, fx=fx, path=Path(name),
                             world_name=SPECS[name], cache=frame_cache).select(start, stop)


def open_folder(root: Path, start: int = 0, end: int = -1,
                frame_cache: DecodedFrameCache | None = None) -> FolderSequence:
    """A SUN3D, TUM RGB-D or 7-Scenes folder, told apart by what it holds; its frames read
    through ``frame_cache`` where one is given."""
    if not root.is_dir():
        raise SequenceError(f"sequence folder {root} does not exist")
    if (root / "image").is_dir():
        reader = read_sun3d(root)
    elif (root / "rgb.txt").is_file():
        reader = read_tum(root)
    elif any(root.glob("frame-*.color.*")):
        reader = read_seven_scenes(root)
    else:
        raise SequenceError(f"{root}: not a SUN3D (image/), TUM RGB-D (rgb.txt) or 7-Scenes "
                            "(frame-*.color.*) folder")
    if not reader.entries:
        raise SequenceError(f"{root}: the sequence holds no frames")
    reader.cache = frame_cache
    chosen = reader.select(start, end)
    if not chosen.entries:
        raise SequenceError(f"{root}: no frame in [{start}, {end}) of its {len(reader)}")
    return chosen
