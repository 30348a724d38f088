"""When the edge closes a slot: the completion rule and the timeout, without DDS
(docs/architecture.md §1).

A slot opens when its ``UploadRequest`` goes out and closes — C_k evicted, bundle adjustment,
the new map published — at the first of:

* **complete**: every requested keyframe is in;
* **short**: the device's ``UplinkThroughput`` says it sent fewer frames than were asked for
  (frames it no longer held after an outage) and all it sent are in — nothing more will come;
* **timeout**: ``timeout_s`` passed since the request (keyframes lost on the way).

Slots close in order (the edge core refuses otherwise): a slot that is due waits for the open
slots before it, so the node asks about the oldest open slot only.

The clock is injected, so tests drive timeouts without waiting. The lifecycle also carries
what the slot's ``MapStats`` reports: compute time spent on it so far, υ of its frames, and
which policy decided it.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Collection
from dataclasses import dataclass
from enum import Enum

from twinslam.uncertainty.map_uncertainty import SlotUncertainty


class Closing(Enum):
    COMPLETE = "complete"
    SHORT = "short"              #: the device sent fewer than requested; all it sent are in
    TIMEOUT = "timeout"


@dataclass
class OpenSlot:
    opened_at: float             #: clock time the request went out
    compute_s: float             #: edge compute spent on the slot so far
    uncertainty: SlotUncertainty | None
    decided_by: str              #: the policy that decided U_k and C_k
    vmax: int = 0                #: the V_max it was planned with (the device's share)
    received_at: float | None = None   #: clock time its frame summaries came (None: opened_at)
    sent: int | None = None      #: frames the device says it sent (its UplinkThroughput)
    #: its tracked frames not asked for: views the shared map covers (SlotPlan.covered)
    covered: int = 0

    def latency_s(self, now: float) -> float:
        """Seconds from the slot's summaries to ``now``."""
        return now - (self.received_at if self.received_at is not None else self.opened_at)


class SlotLifecycle:
    """Open slots from request to map update; ``clock`` returns seconds (monotonic)."""

    def __init__(self, timeout_s: float, clock: Callable[[], float] = time.monotonic) -> None:
        if timeout_s <= 0:
            raise ValueError(f"slot timeout must be > 0 s, got {timeout_s}")
        self.timeout_s = timeout_s
        self.clock = clock
        self.open_slots: dict[int, OpenSlot] = {}

    def open(self, slot: int, compute_s: float, uncertainty: SlotUncertainty | None,
             decided_by: str, vmax: int = 0, received_at: float | None = None,
             covered: int = 0) -> None:
        self.open_slots[slot] = OpenSlot(self.clock(), compute_s, uncertainty, decided_by, vmax,
                                         received_at, covered=covered)

    def charge(self, slot: int, seconds: float) -> None:
        """Compute spent on an open slot (integrating one of its keyframes)."""
        if slot in self.open_slots:
            self.open_slots[slot].compute_s += seconds

    def device_sent(self, slot: int, frames: int) -> None:
        if slot in self.open_slots:
            self.open_slots[slot].sent = frames

    def closing(self, slot: int, requested: Collection[int],
                received: Collection[int]) -> Closing | None:
        """Whether the slot may close now on what has arrived, or because its time is up
        (None: keep waiting)."""
        if set(requested) <= set(received):
            return Closing.COMPLETE
        entry = self.open_slots.get(slot)
        if entry is not None and entry.sent is not None and len(received) >= entry.sent:
            return Closing.SHORT
        if entry is not None and self.clock() - entry.opened_at > self.timeout_s:
            return Closing.TIMEOUT
        return None

    def close(self, slot: int, default_policy: str) -> OpenSlot:
        """Forget the slot; what it carried (a slot never opened carries nothing)."""
        return self.open_slots.pop(slot, None) or OpenSlot(self.clock(), 0.0, None,
                                                           default_policy)
