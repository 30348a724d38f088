"""What every RGB-D sequence yields and promises: the frame, the protocol, the error.

The player, the recorder and the covisibility extractor take any :class:`Sequence` — a
dataset folder, the synthetic room, a recorded bag — so a new source only has to satisfy the
protocol (checked by mypy, not by a common base class), never to be special-cased by a caller.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol, runtime_checkable

import numpy as np

from twinslam.rotations import matrix_from_quaternion, quaternion_from_matrix


class SequenceError(ValueError):
    """A sequence that cannot be read at all (missing folder, missing intrinsics...)."""


@dataclass
class RgbdFrame:
    index: int                     #: position in the sequence (0-based, after skips counted)
    stamp: float                   #: capture time, seconds
    color: np.ndarray              #: H×W×3 uint8, RGB
    depth: np.ndarray | None       #: H×W float32 metres, 0 = no reading; None if absent
    intrinsics: np.ndarray         #: 3×3
    pose: np.ndarray | None        #: 4×4 camera-to-world (ground truth), None if unknown
    name: str = ""                 #: the colour file, for messages


class Sequence(Protocol):
    """Frames in capture order. Iterating is a pass: it may be repeated, and a frame that
    cannot be decoded is skipped, named in ``skipped`` (reset per pass) and logged."""

    path: Path                     #: where it comes from (``synthetic`` for the room)
    kind: str                      #: "7scenes", "sun3d", "tum", "synthetic", "rosbag2"
    intrinsics: np.ndarray         #: 3×3 of the colour camera
    skipped: list[str]             #: what the last pass could not read

    @property
    def stamps(self) -> np.ndarray:
        """Capture time of every frame, seconds, increasing."""
        ...

    def __len__(self) -> int: ...

    def __iter__(self) -> Iterator[RgbdFrame]: ...


@runtime_checkable
class RandomAccessSequence(Sequence, Protocol):
    """A sequence that also reads one frame by position (any order): what playing backwards
    or a scenario's revisit needs. Bags stream and are not random access."""

    def read(self, i: int) -> RgbdFrame | None:
        """Frame ``i``; None (skipped, counted) when it cannot be decoded."""
        ...


def pose_from_xyzq(values: list[float] | np.ndarray) -> np.ndarray:
    """x y z qx qy qz qw (TUM's, the covisibility file's and PoseStamped's order) → 4×4
    camera-to-world; the quaternion is normalised."""
    pose = np.eye(4)
    pose[:3, :3] = matrix_from_quaternion(np.asarray(values[3:7], dtype=np.float64))
    pose[:3, 3] = values[:3]
    return pose


def pose_to_xyzq(pose: np.ndarray) -> np.ndarray:
    """4×4 camera-to-world → x y z qx qy qz qw."""
    return np.concatenate([pose[:3, 3], quaternion_from_matrix(pose[:3, :3])])
