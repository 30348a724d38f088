"""The camera a keyframe was taken with: what projecting a point into its image needs.

The edge learns it from its first keyframe (until then it holds the identity, no camera), and
every step that asks which points a camera sees — restores, fusion, the planner's prediction —
needs the intrinsics and the image's size together; one value carries both.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

#: (height, width) of the images when no keyframe has said otherwise: 7-Scenes', TUM's
DEFAULT_IMAGE_SHAPE = (480, 640)


@dataclass(frozen=True)
class Camera:
    """A pinhole camera: its intrinsics (3×3, pixels) and its image's (height, width)."""

    intrinsics: np.ndarray = field(default_factory=lambda: np.eye(3))
    shape: tuple[int, int] = DEFAULT_IMAGE_SHAPE

    @property
    def known(self) -> bool:
        """Whether the intrinsics are a camera's (a focal length), not the identity the edge
        starts with until its first keyframe brings them."""
        return bool(math.isfinite(self.intrinsics[0, 0]) and self.intrinsics[0, 0] > 1.0)
