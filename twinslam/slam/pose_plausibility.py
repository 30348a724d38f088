"""Poses no camera could have reached: the bounds of a hand-held or head-worn camera's motion,
and the checks that the device's tracking and the edge's keyframe integration apply before a
pose counts.

A pose solver fed by a degenerate map (points nearly on a line, a few outlier matches that
agree, a bundle adjustment that went astray) answers with a pose whatever it is; left alone the
tracker follows it frame after frame, the device uploads keyframes at it, and the edge's map
grows points kilometres away (a held-out LTE run once integrated a keyframe 2·10¹² m from the
origin). What every trusted tracker does is refuse a pose that implies an impossible motion and
call the frame lost, so that relocalisation, with its own gate, brings it back.

The bounds (:class:`MotionBounds`) are a human's, not a dataset's: fitted so that no frame of
a real walk is refused (``bench.motion_bounds`` prints, for any sequence with ground truth, the
largest true step, turn and speed and the margin the bounds keep above them) while a solver
that diverges is caught at its first wrong frame. On the bundled 7-Scenes walk the camera
moves at most 0.036 m and 1.4° between frames and 0.42 m/s over half a second; a head-worn
camera turns at several hundred °/s and a user may run.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from twinslam.rotations import rotation_angle_deg


@dataclass(frozen=True)
class MotionBounds:
    """What a hand-held or head-worn camera can do between the frames of a 30 Hz camera."""

    #: metres between two consecutive frames: 6 m/s at 30 Hz (5.5 times the largest true step
    #: of the 7-Scenes walk, and room for a few centimetres of tracking noise on top)
    max_step_m: float = 0.2
    #: degrees between two consecutive frames: 900 °/s, above the fastest head turns
    max_turn_deg: float = 30.0
    #: metres a second, sustained over ``speed_window`` frames: a running user (7 times the
    #: 7-Scenes walk's 0.42 m/s); a solver drifting off by steps each under ``max_step_m``
    #: trips it within the window
    max_speed_m_s: float = 3.0
    speed_window: int = 15           #: frames (half a second at 30 Hz)
    #: metres a pose may move on top of the motion when the map it is solved against changed
    #: (a map update's correction: the edge's bundle adjustment, a restored keyframe's drift)
    correction_m: float = 0.3

    def __post_init__(self) -> None:
        for name in ("max_step_m", "max_turn_deg", "max_speed_m_s", "correction_m"):
            value = getattr(self, name)
            if not math.isfinite(value) or value <= 0:
                raise ValueError(f"{name} must be finite and > 0, got {value}")
        if self.speed_window < 2:
            raise ValueError(f"speed_window must be >= 2 frames, got {self.speed_window}")


def non_finite(pose: np.ndarray) -> bool:
    """The pose holds a NaN or an infinity, or is not a rigid motion's 4×4 matrix."""
    p = np.asarray(pose, dtype=np.float64)
    return p.shape != (4, 4) or not bool(np.isfinite(p).all())


def implausible_step(previous: np.ndarray, pose: np.ndarray, frames: int,
                     bounds: MotionBounds, map_changed: bool = False) -> str:
    """Why the camera cannot have moved from ``previous`` to ``pose`` (camera-to-world) in
    ``frames`` frames (>= 1), or "" when it can: farther than ``frames`` steps, turned more
    than ``frames`` turns. ``map_changed``: the two poses were solved against different maps,
    whose correction (``correction_m``) is no motion."""
    if non_finite(pose):
        return "a non-finite pose"
    frames = max(int(frames), 1)
    moved = float(np.linalg.norm(pose[:3, 3] - previous[:3, 3]))
    reach = bounds.max_step_m * frames + (bounds.correction_m if map_changed else 0.0)
    if moved > reach:
        return f"moved {moved:.2f} m in {frames} frame(s), more than {reach:.2f} m"
    turned = rotation_angle_deg(previous[:3, :3].T @ pose[:3, :3])
    limit = bounds.max_turn_deg * frames
    if not turned <= limit:                    # (a NaN turn is refused too)
        return f"turned {turned:.0f}° in {frames} frame(s), more than {limit:.0f}°"
    return ""


def implausible_speed(earlier: np.ndarray, pose: np.ndarray, frames: int,
                      frame_rate_hz: float, bounds: MotionBounds,
                      map_changed: bool = False) -> str:
    """Why moving from ``earlier`` to ``pose`` over ``frames`` frames is faster than
    ``max_speed_m_s`` (plus ``correction_m`` when the map changed in between), or ""."""
    seconds = max(int(frames), 1) / frame_rate_hz
    moved = float(np.linalg.norm(pose[:3, 3] - earlier[:3, 3]))
    reach = bounds.max_speed_m_s * seconds + (bounds.correction_m if map_changed else 0.0)
    if moved > reach:
        return (f"moved {moved:.2f} m in {seconds:.2f} s, faster than "
                f"{bounds.max_speed_m_s:.1f} m/s")
    return ""
