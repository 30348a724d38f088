"""A camera that waits for its device: at most ``window`` published frames are left for the
device to pose — the player holds its next frame while that many are.

A device slower than its camera falls behind, and past its camera backlog it drops frames: on
a loaded machine a live run then measures the load, not the device or the edge (a device in
the test suite, its two cores shared with other live runs, tracked 10–15 frames a second and
dropped up to 185 frames of a 30 Hz playback). Paced, the recording's clock stops while the
player holds — the frames keep their recorded spacing in their stamps, which fall behind the
wall clock by the time held — so the device sees every frame, at the pace it can track. What
depends on the wall clock (the uplink's shaping, the edge's answer in time) sees slots that
last longer than their stamps say; a paced run tells how the system does with a fast enough
device, a real-time one how it does on this machine.

The device's ``device/pose`` is the sign a frame was tracked: it is published for every frame
the device takes, tracked or not, stamped with the frame's stamp. A device that never poses
(not started, gone, or one that publishes no poses) would hold the camera for ever: after
``give_up_s`` without a pose the player says so and plays on in real time.
"""

from __future__ import annotations

from collections import deque


class DevicePacing:
    """The frames published and not yet posed, and whether the next may go out (pure: the
    player node feeds it its clock, its publications and the device's poses)."""

    def __init__(self, window: int, give_up_s: float) -> None:
        if window < 0:
            raise ValueError(f"a pacing window is 0 (off) or a number of frames, got {window}")
        self.window = window
        self.give_up_s = give_up_s
        self.gave_up = False                     #: no pose came in time: real time from then on
        self.held_s = 0.0                        #: the recording's clock stopped this long
        self._waiting: deque[int] = deque()      #: stamps (ns) published, not yet posed
        self._hold_since: float | None = None
        self._last_progress: float | None = None

    @property
    def active(self) -> bool:
        return self.window > 0 and not self.gave_up

    @property
    def holding(self) -> bool:
        return self._hold_since is not None

    @property
    def unposed(self) -> int:
        return len(self._waiting)

    def published(self, stamp_ns: int) -> None:
        """A frame went out stamped ``stamp_ns`` (its header's nanoseconds, as the device's
        pose of it will carry them: compared exactly)."""
        if self.active:
            self._waiting.append(stamp_ns)

    def posed(self, stamp_ns: int, now_s: float) -> None:
        """The device posed its frame of ``stamp_ns``: it and every frame before it are done
        (a frame the device skipped is never posed; the next pose counts it)."""
        before = len(self._waiting)
        while self._waiting and self._waiting[0] <= stamp_ns:
            self._waiting.popleft()
        if len(self._waiting) < before:
            self._last_progress = now_s

    def may_publish(self, now_s: float) -> bool:
        """Whether the next frame may go out now; a hold starts at the first False and ends,
        counted in ``held_s``, at the next True."""
        if self.active and len(self._waiting) >= self.window:
            if self._hold_since is None:
                self._hold_since = now_s
            since = max(self._hold_since, self._last_progress or self._hold_since)
            if now_s - since <= self.give_up_s:
                return False
            self.gave_up = True
        if self._hold_since is not None:
            self.held_s += now_s - self._hold_since
            self._hold_since = None
        return True
