"""Camera messages back to arrays: the inverse of :mod:`twinslam.sequence_player.messages`, for the
device's tracker (REP 118 depth encodings; colour as RGB or grey)."""

from __future__ import annotations

from typing import Any

import numpy as np


def image_array(msg: Any) -> np.ndarray:
    """H×W×3 RGB (``rgb8``/``bgr8``) or H×W grey (``mono8``) view of a validated image."""
    h, w = int(msg.height), int(msg.width)
    data = np.asarray(msg.data, dtype=np.uint8)
    if msg.encoding in ("rgb8", "bgr8"):
        rows = data.reshape(h, int(msg.step))[:, :3 * w].reshape(h, w, 3)
        return rows[:, :, ::-1] if msg.encoding == "bgr8" else rows
    if msg.encoding == "mono8":
        return data.reshape(h, int(msg.step))[:, :w]
    raise ValueError(f"colour image encoding {msg.encoding!r} is not rgb8, bgr8 or mono8")


def depth_array(msg: Any) -> np.ndarray:
    """H×W float32 metres, 0 = no reading, from ``16UC1`` millimetres or ``32FC1`` metres."""
    h, w = int(msg.height), int(msg.width)
    raw = np.asarray(msg.data, dtype=np.uint8).reshape(h, int(msg.step))
    if msg.encoding == "16UC1":
        return raw[:, :2 * w].copy().view(np.uint16).astype(np.float32) / 1000.0
    if msg.encoding == "32FC1":
        depth = raw[:, :4 * w].copy().view(np.float32)
        return np.where(np.isfinite(depth) & (depth > 0), depth, 0.0).astype(np.float32)
    raise ValueError(f"depth encoding {msg.encoding!r} is not 16UC1 or 32FC1")
