"""The edge's ledger of a keyframe budget shared by devices with their own slot clocks
: whatever order the devices plan and finish their slots in, the maps never hold
more than V_total together; a share freed by a device that shrinks or vanishes goes to the
others; a budget too small for one more device refuses it with the reason."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from edge_mapper.keyframe_budget import KeyframeBudget, Presence
from twinslam.allocation.allocators import BudgetError, DeviceDemand
from twinslam.uncertainty.map_uncertainty import theorem1_cardinalities


class _Device:
    """A device's map as the edge's planner grows it: Theorem 1's sizes at the granted
    V_max, the map changing when the slot finishes."""

    def __init__(self, name: str) -> None:
        self.name, self.map, self.slot = name, 0, 0
        self.open: dict[int, int] = {}                # slot → map size after it

    def plan(self, budget: KeyframeBudget, now: float, novelty: float, rate: float) -> None:
        grant = budget.grant(self.name, self.slot, DeviceDemand(self.name, self.map, novelty),
                             now, uploads=int(rate * 0.5 / 5.0))
        # the planner sizes against the map the open slots leave (EdgeMapperCore.plan)
        after_open = self.open[max(self.open)] if self.open else self.map
        n_up, n_ev = theorem1_cardinalities(rate, 5.0, 0.5, grant, after_open, 60)
        self.open[self.slot] = after_open + n_up - n_ev
        assert self.open[self.slot] <= grant
        self.slot += 1

    def finish(self, budget: KeyframeBudget) -> None:
        slot = min(self.open)
        self.map = self.open.pop(slot)
        budget.finished(self.name, slot, self.map)


@settings(max_examples=150, deadline=None)
@given(st.sampled_from(["equal", "motion"]), st.integers(2, 4), st.integers(0, 30),
       st.lists(st.tuples(st.integers(0, 3), st.booleans(), st.floats(0, 1),
                          st.sampled_from([0.0, 40.0, 80.0, 200.0])), max_size=120))
def test_maps_never_hold_more_than_v_total_together(allocator: str, n: int, spare: int,
                                                    steps: list) -> None:
    total = 5 * n + spare
    budget = KeyframeBudget(total, allocator, minimum=5)
    devices = [_Device(f"ar{i}") for i in range(n)]
    for d in devices:
        budget.join(d.name, 0.0)
    for t, (who, plan, novelty, rate) in enumerate(steps):
        d = devices[who % n]
        if plan and len(d.open) < 3:
            d.plan(budget, float(t), novelty, rate)
        elif d.open:
            d.finish(budget)
        assert sum(x.map for x in devices) <= total
        budget.check()


def test_a_shrinking_device_frees_keyframes_before_another_grows_into_them() -> None:
    budget = KeyframeBudget(30, "motion", minimum=5)
    a, b = _Device("a"), _Device("b")
    budget.join("a", 0.0)
    budget.join("b", 0.0)
    for t in range(4):                       # a walks into new ground, b stands still
        a.plan(budget, t, 0.9, 200.0)
        b.plan(budget, t, 0.1, 200.0)
        a.finish(budget)
        b.finish(budget)
    assert a.map > b.map and a.map + b.map <= 30
    held = a.map
    for t in range(4, 8):                    # now b moves and a stops: a shrinks first
        b.plan(budget, t, 0.9, 200.0)
        assert b.open[max(b.open)] + a.map <= 30
        a.plan(budget, t, 0.1, 200.0)
        b.finish(budget)
        a.finish(budget)
    assert b.map > a.map and a.map < held


def test_a_silent_device_keeps_its_map_then_its_share_is_reclaimed() -> None:
    budget = KeyframeBudget(30, "equal", minimum=5, silent_after_s=5.0, reclaim_after_s=5.0)
    a, b = _Device("a"), _Device("b")
    budget.join("a", 0.0)
    budget.join("b", 0.0)
    a.plan(budget, 0.0, 0.5, 200.0)
    b.plan(budget, 0.0, 0.5, 200.0)
    a.finish(budget)
    b.finish(budget)
    assert (a.map, b.map) == (15, 15)
    a.plan(budget, 4.0, 0.5, 200.0)
    a.finish(budget)
    assert budget.sweep(4.5) == []
    (event,) = budget.sweep(6.0)             # b says nothing more
    assert (event.device, event.event) == ("b", "silent")
    assert budget.accounts["b"].presence is Presence.SILENT
    a.plan(budget, 8.0, 0.5, 200.0)          # the split leaves b out, its map still counts
    assert budget.accounts["a"].target == 30 and budget.accounts["a"].granted == 15
    a.finish(budget)
    (event,) = budget.sweep(11.0)
    assert (event.device, event.event) == ("b", "reclaimed") and "b" not in budget.accounts
    a.plan(budget, 12.0, 0.5, 200.0)
    a.finish(budget)
    assert a.map == 30


def test_a_silent_device_that_speaks_again_is_active_again() -> None:
    budget = KeyframeBudget(20, "equal", minimum=5, silent_after_s=1.0, reclaim_after_s=60.0)
    budget.join("a", 0.0)
    budget.grant("a", 0, DeviceDemand("a"), 0.0)
    budget.sweep(2.0)
    budget.grant("a", 1, DeviceDemand("a"), 3.0)
    (event,) = budget.sweep(3.0)
    assert (event.device, event.event) == ("a", "active")


def test_a_device_beyond_the_budget_is_refused_and_a_new_one_waits_for_room() -> None:
    budget = KeyframeBudget(12, "equal", minimum=5)
    budget.join("a", 0.0)
    budget.join("b", 0.0)
    with pytest.raises(BudgetError, match="V_total 12 is below 3 devices x 5 keyframes"):
        budget.join("c", 0.0)
    budget = KeyframeBudget(20, "equal", minimum=5)
    a = _Device("a")
    budget.join("a", 0.0)
    a.plan(budget, 0.0, 0.5, 400.0)
    a.plan(budget, 0.1, 0.5, 400.0)          # two slots open: 20 keyframes committed
    budget.join("b", 0.2)
    assert budget.grant("b", 0, DeviceDemand("b"), 0.3) == 0    # nothing free yet
    a.finish(budget)
    a.finish(budget)
    a.plan(budget, 1.0, 0.5, 400.0)          # a shrinks to its share at its next slot
    a.finish(budget)
    assert a.map == 10 and budget.grant("b", 1, DeviceDemand("b"), 1.1) == 10
    with pytest.raises(ValueError, match="unknown allocator"):
        KeyframeBudget(20, "fifo")


def test_a_planner_with_no_budget_uploads_nothing_and_keeps_nothing() -> None:
    assert theorem1_cardinalities(80.0, 5.0, 0.5, 0, 0, 60) == (0, 0)
    assert theorem1_cardinalities(80.0, 5.0, 0.5, 0, 3, 60) == (0, 3)


def test_device_lists_are_checked_before_the_edge_starts() -> None:
    from edge_mapper.parameters import PARAMETERS

    check = next(s.check for s in PARAMETERS if s.name == "devices")
    assert check is not None
    assert check(["ar1", "/lab/ar2/"]) is None
    assert "a device is a namespace name" in (check(["ar-1"]) or "")
    assert "listed twice" in (check(["ar1", "/ar1"]) or "")


def test_a_devices_demand_reads_its_slot_and_map() -> None:
    """Novelty is the share of a tracked frame's points that are the device's own tracks
    (points the edge's map lacks); the value curve rises with the keyframes that hold the
    frames' points; the budget's message lists every device's side."""
    import numpy as np
    from rclpy.serialization import deserialize_message, serialize_message
    from twinslam_msgs.msg import KeyframeBudget as KeyframeBudgetMsg

    from edge_mapper.edge_core import EdgeMapperCore
    from edge_mapper.keyframe_budget import device_demand
    from edge_mapper.messages import keyframe_budget_message
    from edge_mapper.slot_planner import FrameObservations
    from twinslam.policies.rules import make_rule_policy

    core = EdgeMapperCore(make_rule_policy("lff"))
    core.map.add_keyframe(0, np.eye(4))
    for _ in range(40):
        pid = core.map.add_point(np.array([0.0, 0.0, 2.0]), np.zeros(32, np.uint8))
        core.map.observe(0, pid, (320.0, 240.0), 2.0)
    points = frozenset(core.map.keyframes[0].points)
    frames = [FrameObservations(100, points, frozenset(range(40))),          # half new
              FrameObservations(101, points, frozenset()),                   # nothing new
              FrameObservations(102, frozenset(), frozenset(range(9)), False)]   # untracked
    demand = device_demand("ar1", core, frames, 0.0, 3, with_value=True)
    assert demand.novelty == pytest.approx(0.25) and demand.map_size == 1
    assert demand.value is not None and demand.value.tolist() == [0.0, 1.0]
    assert device_demand("ar1", core, frames[2:], 0.0, 3, with_value=False).novelty == 1.0
    # an allocator that reads neither (equal) gets the map's size alone
    assert device_demand("ar1", core, frames, 0.0, 3, with_value=False,
                         with_novelty=False) == DeviceDemand("ar1", map_size=1)

    budget = KeyframeBudget(20, "equal", minimum=5)
    budget.join("ar1", 0.0)
    budget.join("ar2", 0.0)
    budget.grant("ar1", 0, demand, 0.0)
    msg = deserialize_message(serialize_message(keyframe_budget_message(budget, 1.0)),
                              KeyframeBudgetMsg)
    assert (msg.allocator, msg.total, list(msg.devices)) == ("equal", 20, ["ar1", "ar2"])
    assert list(msg.targets) == [10, 10] and list(msg.granted) == [10, 0]
    assert list(msg.committed) == [10, 0] and list(msg.active) == [True, True]


def test_the_first_device_of_a_run_does_not_hold_what_its_slot_cannot_fill() -> None:
    """Alone at first, a device's share is all of V_total, but its first slot can add only
    |U_k| keyframes: it is granted those, and the next device finds room at once."""
    budget = KeyframeBudget(90, "equal", minimum=5)
    budget.join("a", 0.0)
    assert budget.grant("a", 0, DeviceDemand("a"), 0.0, uploads=4) == 4
    budget.join("b", 0.1)
    assert budget.grant("b", 0, DeviceDemand("b"), 0.1, uploads=8) == 8
    assert budget.accounts["a"].target == budget.accounts["b"].target == 45


def test_a_slot_that_never_finished_does_not_hold_its_grant_once_a_later_one_did() -> None:
    """Slots finish in order: a grant whose slot was planned but never finished (dropped while
    the device was silent under load) is released when a later slot finishes, so a device that
    joins gets its minimum (a stale grant of 11 kept one at 4 of 5 for a whole run)."""
    budget = KeyframeBudget(24, "equal", minimum=5)
    for device in ("ar1", "ar2"):
        budget.join(device, 0.0)
    budget.grant("ar1", 3, DeviceDemand("ar1"), 0.0)          # planned, then never finished
    budget.grant("ar1", 4, DeviceDemand("ar1"), 0.0)
    budget.finished("ar1", 4, 3)
    assert budget.accounts["ar1"].committed == 3
    budget.join("ar3", 0.0)
    assert budget.grant("ar3", 0, DeviceDemand("ar3"), 0.0) >= 5
    budget.check()
