"""Camera messages back to arrays: the inverse of :mod:`twinslam.sequence_player.messages`, for the
device's tracker (REP 118 depth encodings; colour as RGB or grey), and the intake that pairs
and decodes them. Pure logic, no DDS."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass

import numpy as np
from sensor_msgs.msg import Image

from device_tracker.frame_pairing import FramePairing
from msg_schemas import qos
from msg_schemas.headers import stamp_key, stamp_seconds

#: what the device's warning says when it dropped frames it could not keep up with: a run's
#: logs are searched for it (a live figure of a device that dropped frames measures the load)
FELL_BEHIND = "behind the camera"


def image_array(msg: Image) -> np.ndarray:
    """H×W×3 RGB (``rgb8``/``bgr8``) or H×W grey (``mono8``) view of a validated image."""
    h, w = int(msg.height), int(msg.width)
    data = np.asarray(msg.data, dtype=np.uint8)
    if msg.encoding in ("rgb8", "bgr8"):
        rows = data.reshape(h, int(msg.step))[:, :3 * w].reshape(h, w, 3)
        return rows[:, :, ::-1] if msg.encoding == "bgr8" else rows
    if msg.encoding == "mono8":
        return data.reshape(h, int(msg.step))[:, :w]
    raise ValueError(f"colour image encoding {msg.encoding!r} is not rgb8, bgr8 or mono8")


def depth_array(msg: Image) -> np.ndarray:
    """H×W float32 metres, 0 = no reading, from ``16UC1`` millimetres or ``32FC1`` metres."""
    h, w = int(msg.height), int(msg.width)
    raw = np.asarray(msg.data, dtype=np.uint8).reshape(h, int(msg.step))
    if msg.encoding == "16UC1":
        # one pass: the rows copied only where the step pads them, converted while divided
        # (the float32 quotients of astype(float32) / 1000, in 0.1 ms instead of 1 ms)
        mm = np.ascontiguousarray(raw[:, :2 * w]).view(np.uint16)
        return np.divide(mm, 1000.0, dtype=np.float32)
    if msg.encoding == "32FC1":
        depth = raw[:, :4 * w].copy().view(np.float32)
        return np.where(np.isfinite(depth) & (depth > 0), depth, 0.0).astype(np.float32)
    raise ValueError(f"depth encoding {msg.encoding!r} is not 16UC1 or 32FC1")


@dataclass(frozen=True)
class CameraFrame:
    """A colour image paired with its depth image by stamp, decoded."""

    color: np.ndarray
    depth: np.ndarray | None
    stamp: float                   #: seconds
    color_msg: Image               #: kept with the frame's upload when the device sends images


class CameraIntake:
    """Colour and depth messages in, decoded frames out in stamp order
    (:mod:`device_tracker.frame_pairing`); a frame that cannot be had — a depth image whose
    colour never came, an image that does not decode — is skipped, counted and said why.

    The node takes the camera's messages as they come and tracks on a thread of its own, so
    the frames waiting for the tracker wait here: at most ``backlog`` of them (the camera
    topics' reader depth, which bounded the wait while the executor tracked); a device further
    behind its camera drops its oldest waiting frames, counted with the skipped ones."""

    def __init__(self, backlog: int = qos.CAMERA.depth) -> None:
        if backlog < 1:
            raise ValueError(f"a camera backlog holds at least 1 frame, got {backlog}")
        self.pairing = FramePairing()
        self.backlog = backlog
        self.skipped = 0
        self._behind = 0                 #: frames dropped for the backlog, not yet said
        self._dropped_upto = -1          #: the newest stamp (ns) dropped for the backlog

    def add(self, kind: str, msg: Image) -> None:
        """``kind``: "color" or "depth". The other half of a frame dropped for the backlog,
        come late, is dropped too: tracked, it would come after newer frames."""
        key = stamp_key(msg.header)
        if key <= self._dropped_upto:
            return
        self.pairing.add(kind, key, msg)
        while len(self.pairing.pending) > self.backlog:
            oldest = min(self.pairing.pending)
            del self.pairing.pending[oldest]
            self._dropped_upto = max(self._dropped_upto, oldest)
            self.skipped += 1
            self._behind += 1

    @property
    def waiting(self) -> int:
        """Frames in, not yet handed out (complete or waiting for their other half)."""
        return len(self.pairing.pending)

    def frames(self, skip: Callable[[str], None]) -> Iterator[CameraFrame]:
        """The frames complete now; ``skip(reason)`` for each one dropped."""
        if self._behind:
            skip(f"the tracker fell {self.backlog} frames {FELL_BEHIND}: its "
                 f"{self._behind} oldest waiting frame(s) dropped")
            self._behind = 0
        for frame in self.pairing.ready():
            if frame.color is None:
                self.skipped += 1
                skip(f"depth image of stamp {frame.stamp_key / 1e9:.3f} s without its colour "
                     f"image (newest colour {frame.newest_color / 1e9:.3f} s): skipped")
                continue
            try:
                color = image_array(frame.color)
                depth = depth_array(frame.depth) if frame.depth is not None else None
            except ValueError as exc:
                self.skipped += 1
                skip(f"frame skipped: {exc}")
                continue
            yield CameraFrame(color, depth, stamp_seconds(frame.color.header), frame.color)
