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
    """U_k, C_k and the archived keyframes R_k brought back: V_{k+1} = (V_k ∪ U_k ∪ R_k) \\ C_k.

    ``restore`` is empty for the paper's policies; a restoring one (:mod:`.restoring`) names
    archived keyframes the map takes back over the downlink, and evicts one more map keyframe
    for each that does not fit under V_max."""

    upload: list[int]
    evict: list[int]
    restore: list[int] = field(default_factory=list)


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
    #: keyframes evicted earlier that the edge still holds, least recently useful first
    archive: list[int] = field(default_factory=list)
    n_restore: int = 0                 #: at most this many of them may come back this slot
    vmax: int | None = None            #: V_max (restores beyond it cost an eviction each)
    #: the map's keyframes in the order they entered it — uploaded, restored from the archive
    #: or adopted from another device's map — earliest first (None: as ``map_frames``). Ids
    #: are capture order only for a map that never takes a keyframe back: a restored one is
    #: old by capture, a copy of another device's tagged as the newest
    entered: list[int] | None = None

    def entry_order(self) -> list[int]:
        """The map's keyframes, earliest entered first: what "the oldest map frame" means to
        a rule (:attr:`entered`; the paper's map, which only ever adds uploads, in id
        order)."""
        return list(self.map_frames) if self.entered is None else list(self.entered)

    def weight_block(self, a: list[int], b: list[int]) -> np.ndarray:
        return np.asarray(self.weights(a, b))

    def evictions_with(self, n_restored: int) -> int:
        """|C_k| when ``n_restored`` archived keyframes come back: Theorem 1's, plus one for
        each that does not fit under V_max."""
        return restore_evictions(self.n_evict, len(self.map_frames) + self.n_upload,
                                 n_restored, self.vmax)


def restore_evictions(n_evict: int, pool: int, n_restored: int, vmax: int | None) -> int:
    """Evictions a slot makes: Theorem 1's ``n_evict`` out of ``pool`` = |V_k| + |U_k|
    keyframes, plus the restores that would push the map over ``vmax``."""
    if vmax is None or n_restored == 0:
        return n_evict
    return n_evict + max(0, pool - n_evict + n_restored - vmax)


def check_map_action(slot: int, n_upload: int, n_evict: int, candidates: Collection[int],
                     map_frames: Collection[int], action: MapAction,
                     archive: Collection[int] = (), n_restore: int = 0,
                     vmax: int | None = None) -> None:
    """Raise :class:`ActionError` unless ``action`` uploads ``n_upload`` distinct frames of
    ``candidates``, restores at most ``n_restore`` distinct keyframes of ``archive`` and evicts
    distinct frames of the map or the uploads, as many as Theorem 1 says plus one a restore
    beyond ``vmax``; used by the simulator and by the edge node alike."""
    restore = list(action.restore)
    if len(set(restore)) != len(restore) or len(restore) > n_restore:
        raise ActionError(f"slot {slot}: restore {len(restore)} distinct keyframes, at most "
                          f"{n_restore} may come back")
    unknown = [f for f in restore if f not in archive]
    if unknown:
        raise ActionError(f"slot {slot}: restores {sorted(unknown)} are not in the archive")
    n_evict = restore_evictions(n_evict, len(map_frames) + n_upload, len(restore), vmax)
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
