"""A standby edge (``standby:=true``) taking over a device whose edge stopped answering.

Several ``edge_mapper`` processes — on one host or across hosts over DDS — can share the
devices of a site; each device is served by one of them. A standby edge watches every device
namespace that publishes frame summaries and that it does not serve: the device's summaries
and the upload requests some edge answers them with. Once ``takeover_slots`` of the device's
slots went unanswered — its edge died, or was never there — the standby serves the device,
from the device's checkpoint where the edges share the ``checkpoint`` path (the map, its
version and its archive as the dead edge last wrote them: the device, which ignores map
versions older than the one it holds, takes the next update). The protocol decides, not
DDS's liveliness: a killed process leaves the graph only when its participant's lease runs
out (Fast DDS: 20 s), a slot unanswered shows within the slot.

A standby that serves a device it took over gives it back when another edge answers the
device again (two publishers of its upload requests: the device's own edge restarted), so
that the device never has two edges deciding its slots.
"""

from __future__ import annotations

from dataclasses import dataclass, field

#: a device's slots unanswered before a standby takes it over: one late answer is no death
TAKEOVER_SLOTS = 3


@dataclass
class UnansweredSlots:
    """One device's slots as a standby edge hears them: the newest summaries and the newest
    slot some edge answered (-1: none yet)."""

    takeover_slots: int = TAKEOVER_SLOTS
    newest_summaries: int = -1
    newest_answer: int = -1
    #: slots whose summaries came since the newest answer (a device's slot numbers restart
    #: when it restarts: counting them, not subtracting numbers)
    unanswered: set[int] = field(default_factory=set)

    def summaries(self, slot: int) -> None:
        """The device summarised ``slot``."""
        self.newest_summaries = max(self.newest_summaries, slot)
        if slot > self.newest_answer:
            self.unanswered.add(slot)

    def answered(self, slot: int) -> None:
        """Some edge asked the device for ``slot``'s uploads."""
        self.newest_answer = max(self.newest_answer, slot)
        self.unanswered = {s for s in self.unanswered if s > slot}

    @property
    def due(self) -> bool:
        """Whether the device has gone ``takeover_slots`` slots without an answer."""
        return len(self.unanswered) >= self.takeover_slots
