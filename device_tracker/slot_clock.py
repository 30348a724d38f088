"""Which slot a frame belongs to, from its stamp — not from how many frames came before it.

A slot k lasts ``slot_frames`` nominal frame periods (paper §III: F frames at 30 Hz). Counting
frames would shift every later slot by one whenever a frame is lost between the camera and the
tracker (a dropped DDS sample, a corrupt image the player skips), so the device and the edge
would disagree about which frames a slot holds and when the uplink's rate changes. The stamp
decides instead: slot k holds the frames stamped in [t0 + k·T, t0 + (k+1)·T), T =
``slot_frames`` / ``frame_rate_hz``, t0 the first frame's stamp, with half a frame period of
tolerance so that a stamp jittering just before a boundary still lands in its slot.

A frame is its slot's **last** when a frame one period later would fall into the next slot; a
slot whose last frame never came ends when the first frame of a later slot arrives.
"""

from __future__ import annotations

import math


class SlotClock:
    """Slot index of a stamp (seconds); t0 is the first stamp asked about."""

    def __init__(self, slot_frames: int, frame_rate_hz: float) -> None:
        if slot_frames < 1:
            raise ValueError(f"slot_frames must be >= 1, got {slot_frames}")
        if not frame_rate_hz > 0 or not math.isfinite(frame_rate_hz):
            raise ValueError(f"frame_rate_hz must be a positive number, got {frame_rate_hz}")
        self.slot_frames = slot_frames
        self.period_s = 1.0 / frame_rate_hz
        self.slot_s = slot_frames * self.period_s
        self.t0: float | None = None

    def slot_of(self, stamp: float) -> int:
        """The slot ``stamp`` falls in (0 for the first stamp; never negative)."""
        if self.t0 is None:
            self.t0 = stamp
        return max(0, math.floor((stamp - self.t0 + 0.5 * self.period_s) / self.slot_s))

    def is_last(self, stamp: float) -> bool:
        """No further frame of this stamp's slot is due (the next one starts a new slot)."""
        return self.slot_of(stamp + self.period_s) > self.slot_of(stamp)
