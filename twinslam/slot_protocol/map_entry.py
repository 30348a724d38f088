"""When a keyframe entered a map: the order LFF's and PU's "oldest" reads.

A map that takes keyframes back (restores from the archive, copies adopted from another
device's map) cannot read ids as capture order: a restored keyframe is old by capture but new
to the map. The edge's back end and the simulator each record, for every keyframe of their
map, the slot it entered and how — a slot's uploads while it runs, its restores at its end,
after them — and both hand the policy the map in that order
(:attr:`~twinslam.policies.actions.SlotObservation.entered`). One convention for both, so that
the simulator stays calibrated against the edge.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping

#: how a keyframe entered the map, the second half of its entry: (slot, UPLOADED) or
#: (slot, RESTORED)
UPLOADED, RESTORED = 0, 1
#: the entry of a keyframe with none recorded (a checkpoint written before entries were
#: kept): before every recorded one
UNRECORDED = (-1, UPLOADED)


def entry_order(keyframes: Iterable[int], entered: Mapping[int, tuple[int, int]]) -> list[int]:
    """``keyframes`` in the order they entered the map (``entered``: keyframe → (slot, how)),
    earliest first, ties by id."""
    return sorted(keyframes, key=lambda k: (*entered.get(k, UNRECORDED), k))
