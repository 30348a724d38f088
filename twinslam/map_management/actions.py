"""What a map-management policy sees and answers each slot (docs/architecture.md §2, Theorem 1).

The simulator, the edge's slot planner and every policy exchange these types, so they live
below all of them: a policy can be written, tested and run without the simulator or a node.
"""

from __future__ import annotations

from collections.abc import Collection
from dataclasses import dataclass, field
from typing import Any

import numpy as np


class ActionError(ValueError):
    """An action that breaks the slot's constraints (wrong sizes, unknown frames)."""


@dataclass
class MapAction:
    upload: list[int]
    evict: list[int]


@dataclass
class SlotObservation:
    """What a policy may know at the end of slot k (ids are frame-instance ids)."""

    slot: int
    map_frames: list[int]              #: V^e_k, oldest first (index 0 is the anchor)
    candidates: list[int]              #: F_k in capture order
    n_upload: int                      #: |U_k|
    n_evict: int                       #: |C_k|
    rate_mbps: float
    rate_state: int
    rate_history: list[int]            #: state indices d_{k-τ..k}
    n_states: int
    weights: Any = field(repr=False, default=None)   #: callable(ids_a, ids_b) -> block

    def weight_block(self, a: list[int], b: list[int]) -> np.ndarray:
        return np.asarray(self.weights(a, b))


def check_map_action(slot: int, n_upload: int, n_evict: int, candidates: Collection[int],
                     map_frames: Collection[int], action: MapAction) -> None:
    """Raise :class:`ActionError` unless ``action`` uploads ``n_upload`` distinct frames of
    ``candidates`` and evicts ``n_evict`` distinct frames of the map or the uploads (Theorem 1's
    sizes); used by the simulator and by the edge node alike."""
    up, ev = list(action.upload), list(action.evict)
    up_set, ev_set = set(up), set(ev)
    if len(up) != n_upload or len(up_set) != len(up):
        raise ActionError(f"slot {slot}: upload {len(up)} distinct frames, Theorem 1 asks for "
                          f"{n_upload}")
    outside = [f for f in up if f not in candidates]
    if outside:
        raise ActionError(f"slot {slot}: uploads {sorted(outside)} are not frames of this slot")
    if len(ev) != n_evict or len(ev_set) != len(ev):
        raise ActionError(f"slot {slot}: evict {len(ev)} frames, Theorem 1 asks for {n_evict}")
    stray = ev_set - set(map_frames) - up_set
    if stray:
        raise ActionError(f"slot {slot}: evictions {sorted(stray)} are neither in the map nor "
                          "uploaded")
