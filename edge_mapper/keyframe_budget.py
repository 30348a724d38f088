"""One edge, many devices: the shared keyframe budget V_total, slot by slot.

Devices keep their own slot clocks, so the budget is granted per device-slot: when device i
plans slot k, the allocator (:mod:`twinslam.allocation.allocators`) splits V_total between
the active devices by their latest demands, and i plans with

    grant_i = min(target_i, V_total − Σ_{j≠i} committed_j),

where committed_j = max(j's map size, the grants of j's open slots) is the most j's map can
hold until its open slots finish. A device's map after a slot is at most that slot's grant
(the planner's Theorem 1 sizes), so Σ_i map_i ≤ Σ_i committed_i ≤ V_total at every moment
— a device whose share shrank frees its keyframes at its next slot before another device can
grow into them. Map sizes here are those of the maps the edge publishes, at slot ends: while
slots overlap, the edge may hold the next slot's uploads a moment before that slot's
evictions apply (:mod:`edge_mapper.edge_core`), never in a map a device receives. A new
device joins the split at its first summaries and may get less than its share (or nothing: it
then uploads nothing that slot) until the others have shrunk.

A device that sends no summaries for ``silent_after_s`` is silent: it keeps its map and its
committed keyframes but drops out of the split; after ``reclaim_after_s`` more its budget is
reclaimed (its map released) and the others grow into it at their next slots. A silent device
that speaks again is active again; a reclaimed one starts afresh.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from enum import Enum

import numpy as np

from edge_mapper.edge_core import EdgeMapperCore
from edge_mapper.slot_planner import FrameObservations
from twinslam.allocation.allocators import (
    ALLOCATORS,
    BudgetError,
    DeviceDemand,
    allocate,
    check_budget,
)
from twinslam.allocation.budget_value import budget_value, expected_uploads
from twinslam.slot_protocol.lost_frame_rule import MIN_INLIERS
from twinslam.uncertainty.map_uncertainty import theorem1_uploads


class Presence(Enum):
    ACTIVE = "active"
    SILENT = "silent"


@dataclass
class DeviceAccount:
    """One device's side of the ledger."""

    device: str
    demand: DeviceDemand
    last_seen: float                        #: monotonic seconds of its last summaries
    map_size: int = 0                       #: keyframes of its last published map
    target: int = 0                         #: the allocator's share at its last plan
    granted: int = 0                        #: V_max its last plan was given
    open_grants: dict[int, int] = field(default_factory=dict)   #: slot → grant
    presence: Presence = Presence.ACTIVE

    @property
    def committed(self) -> int:
        """The most keyframes its map can hold until its open slots finish."""
        return max([self.map_size, *self.open_grants.values()])


@dataclass(frozen=True)
class BudgetEvent:
    """A change of a device's presence, for the node to log and act on."""

    device: str
    event: str                               #: "silent", "active" or "reclaimed"
    seconds: float                           #: how long it had been quiet


class KeyframeBudget:
    """The ledger of V_total across devices (no DDS, no clocks of its own: callers pass
    monotonic seconds)."""

    def __init__(self, total: int, allocator: str = "equal", minimum: int = 5,
                 fairness: float = 0.0, silent_after_s: float = 10.0,
                 reclaim_after_s: float = 60.0) -> None:
        if allocator not in ALLOCATORS:
            raise ValueError(f"unknown allocator {allocator!r}: one of {', '.join(ALLOCATORS)}")
        check_budget(total, 1, minimum)
        if not (silent_after_s > 0 and reclaim_after_s >= 0):
            raise ValueError("silent_after_s must be > 0 and reclaim_after_s >= 0")
        self.total, self.allocator, self.minimum = int(total), allocator, int(minimum)
        self.fairness = float(fairness)
        self.silent_after_s, self.reclaim_after_s = silent_after_s, reclaim_after_s
        self.accounts: dict[str, DeviceAccount] = {}
        self._events: list[BudgetEvent] = []     #: silent devices heard again, until swept

    @property
    def active(self) -> list[str]:
        return [d for d, a in self.accounts.items() if a.presence is Presence.ACTIVE]

    def join(self, device: str, now: float) -> None:
        """Take ``device`` in; BudgetError when V_total cannot give every active device its
        minimum with it (the device is then not served)."""
        if device in self.accounts:
            return
        check_budget(self.total, len(self.active) + 1, self.minimum)
        self.accounts[device] = DeviceAccount(device, DeviceDemand(device), now)

    def grant(self, device: str, slot: int, demand: DeviceDemand, now: float,
              uploads: int | None = None) -> int:
        """The V_max ``device`` plans ``slot`` with (see the module's rule); its demand and
        presence are brought up to date first. ``uploads``: the most keyframes this slot can
        add (Theorem 1's |U_k|); a grant never exceeds what the map can reach with them, so
        a device does not hold keyframes it cannot fill while another waits for room (the
        first device of a run would otherwise hold all of V_total for its first slot)."""
        account = self.accounts[device]
        account.demand = demand
        if account.presence is Presence.SILENT:
            check_budget(self.total, len(self.active) + 1, self.minimum)
            self._events.append(BudgetEvent(device, "active", now - account.last_seen))
            account.presence = Presence.ACTIVE
        account.last_seen = now
        active = [self.accounts[d] for d in self.active]
        targets = allocate(self.allocator, self.total, [a.demand for a in active],
                           self.minimum, self.fairness)
        for a, target in zip(active, targets, strict=True):
            a.target = target
        others = sum(a.committed for d, a in self.accounts.items() if d != device)
        grant = max(0, min(account.target, self.total - others))
        if uploads is not None:
            grant = min(grant, account.committed + max(0, uploads))
        account.granted = grant
        account.open_grants[slot] = grant
        return grant

    def finished(self, device: str, slot: int, map_size: int) -> None:
        """``device``'s ``slot`` finished with ``map_size`` keyframes: the map it publishes
        (between two slot ends the edge may already hold the next slot's uploads before that
        slot's evictions apply — at most one slot's uploads, never in a published map). Its
        earlier slots are over too."""
        account = self.accounts.get(device)
        if account is None:
            return
        # a device's slots finish in order: one that never finished before this one (planned,
        # then dropped) must not hold its grant for ever — measured under load, a stale grant
        # of 11 kept a joining device below its minimum for the rest of the run
        for done in [k for k in account.open_grants if k <= slot]:
            del account.open_grants[done]
        account.map_size = map_size

    def sweep(self, now: float) -> list[BudgetEvent]:
        """Silence and reclaim by the clock; what changed since the last sweep."""
        events, self._events = self._events, []
        for device, account in list(self.accounts.items()):
            quiet = now - account.last_seen
            if account.presence is Presence.ACTIVE and quiet >= self.silent_after_s:
                account.presence = Presence.SILENT
                events.append(BudgetEvent(device, "silent", quiet))
            elif (account.presence is Presence.SILENT
                  and quiet >= self.silent_after_s + self.reclaim_after_s):
                del self.accounts[device]
                events.append(BudgetEvent(device, "reclaimed", quiet))
        return events

    def committed_total(self) -> int:
        return sum(a.committed for a in self.accounts.values())

    def check(self) -> None:
        """AssertionError when the ledger breaks its invariant (tests and debugging)."""
        assert self.committed_total() <= self.total, (
            f"{self.committed_total()} keyframes committed of {self.total}")


def device_demand(device: str, core: EdgeMapperCore, frames: Sequence[FrameObservations],
                  rate_mbps: float, max_budget: int, with_value: bool,
                  next_state_probs: Sequence[float] = (),
                  state_rates_mbps: Sequence[float] = (), with_novelty: bool = True
                  ) -> DeviceDemand:
    """What ``device``'s slot says of its need: its map size, its novelty (the share of the
    points its tracked frames observe that are its own tracks, not the edge's map points;
    only ``with_novelty``, else 0: the ``motion`` allocator alone reads it, and resolving
    every frame's points took 6 % of a fifty-device edge's slot thread under ``equal``)
    and, for the ``twin`` allocator, its value curve over budgets 0 … ``max_budget``. The
    uploads the curve expects come from its twin's next-state distribution when one is given
    (``next_state_probs`` over ``state_rates_mbps``), else from this slot's rate."""
    if not (with_novelty or with_value):
        return DeviceDemand(device, len(core.slice.keyframes))
    planner, cfg = core.planner, core.slot_config
    by_id = {f.frame_id: f for f in frames}
    points = [planner.points_of(by_id, f.frame_id) for f in frames if f.tracked]
    novelty = 0.0
    if with_novelty:
        shares = [float(np.count_nonzero(p < 0)) / p.size for p in points if p.size]
        novelty = float(np.mean(shares)) if shares else 1.0
    value = None
    if with_value:
        if len(next_state_probs) and len(next_state_probs) == len(state_rates_mbps):
            uploads = expected_uploads(next_state_probs, state_rates_mbps, cfg.alpha_mbit,
                                       cfg.d_req_s, len(frames), cfg.deadline_s(len(frames)))
        else:
            uploads = slot_uploads(core, rate_mbps, len(frames))
        keyframes = [core.slice.point_array(k) for k in core.slice.keyframe_ids()]
        value = budget_value(keyframes, points, uploads, MIN_INLIERS, max_budget)
    return DeviceDemand(device, len(core.slice.keyframes), novelty, value)


__all__ = ["BudgetError", "BudgetEvent", "DeviceAccount", "KeyframeBudget", "Presence"]


def slot_uploads(core: EdgeMapperCore, rate_mbps: float, n_frames: int) -> int:
    """Theorem 1's |U_k| for a slot of ``n_frames`` of ``core``'s device at ``rate_mbps``:
    the most keyframes the slot can add, which bounds the device's grant."""
    cfg = core.slot_config
    return theorem1_uploads(rate_mbps, cfg.alpha_mbit, cfg.d_req_s, n_frames,
                            cfg.deadline_s(n_frames), core.planner.waited_mbit)
