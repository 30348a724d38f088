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

Several cameras at once (a fleet, two users in one room) each paced alone would drift apart:
the camera of the slowest device falls behind the others in its recording, and where the walks
meet — a merge, a shared anchor — they would meet at other times than the recording has them.
Players of one *group* keep one recording clock instead: each tells the group how long it has
held and whether it holds now for its own device (:meth:`DevicePacing.told`); each holds while
another waits for its device, and until it has held as long as the one that held longest
(:meth:`DevicePacing.group_said`). A camera held for the group alone says it does not wait for a
device and holds exactly up to the group's time, never beyond: no two cameras can keep each
other waiting. A camera that waits for its device but has not said so for ``silence_s`` (its
process gone) is taken at its last word.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

#: a camera this little behind its group's clock does not hold for it (the group's word
#: travels with a few milliseconds' jitter)
GROUP_SLACK_S = 0.002


@dataclass(frozen=True)
class _Word:
    """What another camera of the group said last, and when it was heard."""

    held_s: float
    waiting: bool
    heard_s: float


class DevicePacing:
    """The frames published and not yet posed, and whether the next may go out (pure: the
    player node feeds it its clock, its publications, the device's poses and what the other
    cameras of its group said)."""

    def __init__(self, window: int, give_up_s: float, silence_s: float = 5.0) -> None:
        if window < 0:
            raise ValueError(f"a pacing window is 0 (off) or a number of frames, got {window}")
        self.window = window
        self.give_up_s = give_up_s
        self.silence_s = silence_s
        self.gave_up = False                     #: no pose came in time: real time from then on
        self.held_s = 0.0                        #: the recording's clock stopped this long
        self._waiting: deque[int] = deque()      #: stamps (ns) published, not yet posed
        self._hold_since: float | None = None
        #: when the device fell a window behind in the hold under way (None: it has not, the
        #: group alone holds this camera)
        self._device_since: float | None = None
        self._last_progress: float | None = None
        self._group: dict[str, _Word] = {}       #: the other cameras, by name

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

    def group_said(self, camera: str, held_s: float, waiting: bool, now_s: float) -> None:
        """Camera ``camera`` of the group has held ``held_s`` in all and, with ``waiting``,
        holds on for its device (its held time growing with the clock until it says more)."""
        self._group[camera] = _Word(held_s, waiting, now_s)

    def group_held_at(self, now_s: float) -> float:
        """The longest any other camera of the group has held by ``now_s``."""
        most = 0.0
        for word in self._group.values():
            grown = min(now_s - word.heard_s, self.silence_s) if word.waiting else 0.0
            most = max(most, word.held_s + max(grown, 0.0))
        return most

    def told(self, now_s: float) -> tuple[float, bool]:
        """What this camera tells the group: how long it has held by ``now_s``, the hold under
        way counted (one for the device in full, one for the group alone up to the group's
        time and no further), and whether it holds now for its device."""
        if self._hold_since is None:
            return self.held_s, False
        held = self.held_s + now_s - self._hold_since
        if self._device_since is None:
            return min(held, max(self.held_s, self.group_held_at(now_s))), False
        return held, self._device_behind(now_s)

    def group_wait_s(self, now_s: float) -> float:
        """How much longer the group keeps this camera waiting from ``now_s``, as far as it
        has said (0: it does not; a camera that waits for its device may say more)."""
        behind = self.group_held_at(now_s) - self.told(now_s)[0]
        return behind if behind > GROUP_SLACK_S else 0.0

    def may_publish(self, now_s: float) -> bool:
        """Whether the next frame may go out now; a hold starts at the first False and ends,
        counted in ``held_s``, at the next True."""
        device = self._device_behind(now_s)
        if device or self.group_wait_s(now_s) > 0.0:
            if self._hold_since is None:
                self._hold_since = now_s
            if device and self._device_since is None:
                self._device_since = now_s
            return False
        if self._hold_since is not None:
            self.held_s = self.told(now_s)[0]
            self._hold_since = self._device_since = None
        return True

    def _device_behind(self, now_s: float) -> bool:
        """Whether the device has a window of frames to pose — until it made no progress for
        ``give_up_s`` (then never again)."""
        if not (self.active and len(self._waiting) >= self.window):
            return False
        since = max(self._device_since if self._device_since is not None else now_s,
                    self._last_progress or 0.0)
        if now_s - since <= self.give_up_s:
            return True
        self.gave_up = True
        return False
