"""The camera the edge learns from its first keyframe."""

from __future__ import annotations

import math

import numpy as np


def has_camera(intrinsics: np.ndarray) -> bool:
    """Whether ``intrinsics`` are a camera's (a focal length), not the identity the edge
    starts with until its first keyframe brings them."""
    return bool(math.isfinite(intrinsics[0, 0]) and intrinsics[0, 0] > 1.0)
