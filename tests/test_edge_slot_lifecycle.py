"""The edge's slot lifecycle and live policy control, driven without DDS: when a slot closes
(all keyframes in, all the device sent in, or the timeout on an injected clock), and how live
parameter changes and the twin's fallback decide the next slot."""

from __future__ import annotations

import numpy as np
import pytest

from edge_mapper.parameters import PARAMETERS
from edge_mapper.policy_control import POLICY_KEYS, PolicyControl
from edge_mapper.slot_lifecycle import Closing, SlotLifecycle
from tests.test_uplink_shaper import VirtualTime


def test_a_slot_closes_when_all_requested_keyframes_are_in() -> None:
    slots = SlotLifecycle(10.0, VirtualTime().clock)
    slots.open(3, 0.01, None, "adapt")
    assert slots.closing(3, [30, 31], {30}) is None
    assert slots.closing(3, [30, 31], {30, 31}) is Closing.COMPLETE
    assert slots.closing(4, [], set()) is Closing.COMPLETE       # nothing asked for


def test_a_slot_closes_short_once_everything_the_device_sent_is_in() -> None:
    slots = SlotLifecycle(10.0, VirtualTime().clock)
    slots.open(3, 0.0, None, "lff")
    slots.device_sent(3, 1)                 # it no longer held the other frame
    assert slots.closing(3, [30, 31], set()) is None
    assert slots.closing(3, [30, 31], {31}) is Closing.SHORT
    slots.device_sent(9, 0)                 # a slot never opened: ignored
    assert 9 not in slots.open_slots


def test_timeouts_follow_the_injected_clock_and_closing_forgets_the_slot() -> None:
    clock = VirtualTime()
    clock.now = 0.0
    slots = SlotLifecycle(2.0, clock.clock)
    slots.open(1, 0.02, None, "adapt")
    clock.now += 1.0
    slots.open(2, 0.03, None, "pu")
    slots.charge(2, 0.5)
    clock.now += 1.5                          # slot 1 is 2.5 s old, slot 2 1.5 s
    assert slots.closing(1, [10], set()) is Closing.TIMEOUT
    assert slots.closing(2, [20], set()) is None
    assert slots.closing(2, [20], {20}) is Closing.COMPLETE        # in time beats late
    clock.now += 1.0
    assert slots.closing(2, [20], set()) is Closing.TIMEOUT
    closed = slots.close(2, "lff")
    assert closed.decided_by == "pu" and closed.compute_s == pytest.approx(0.53)
    assert slots.closing(2, [20], set()) is None                   # closed: forgotten
    assert slots.close(7, "lff").decided_by == "lff"      # never opened: the current policy
    with pytest.raises(ValueError, match="timeout"):
        SlotLifecycle(0.0)


def _live(**changes: object) -> dict[str, object]:
    values = {"policy": "adapt", "policy_checkpoint": "", "fallback_policy": "adapt",
              "latent_max_age": 2}
    return {**values, **changes}


def test_live_parameters_are_the_nodes_live_parameters() -> None:
    """The policy's keys and V_max (the core's) are every live parameter of the node."""
    assert set(POLICY_KEYS) | {"vmax"} == {p.name for p in PARAMETERS if p.live}
    assert set(_live()) == set(POLICY_KEYS)


def test_a_live_policy_change_applies_and_a_refused_one_keeps_the_old_policy() -> None:
    warmed: list[str] = []
    control = PolicyControl(_live(), lambda p: warmed.append(p.name))
    assert control.policy.name == "adapt" and warmed == ["adapt"]
    assert control.apply(_live(), 1) == []                       # nothing changed
    notes = control.apply(_live(policy="lff"), 2)
    assert control.policy.name == "lff"
    assert [n.level for n in notes] == ["info"] and "policy lff" in notes[0].text
    notes = control.apply(_live(policy="mbrl:/nowhere.pt"), 3)
    assert control.policy.name == "lff" and control.policy_name == "lff"
    assert notes[0].level == "error" and "lff goes on deciding" in notes[0].text
    assert control.apply(_live(policy="mbrl:/nowhere.pt"), 4) == []   # not retried
    assert control.decided(4) == ("lff", [])


class _TwinPolicy:
    name, feature_size, uses_twin = "mbrl-variational", 4, True

    def reset(self, seed: int | None = None) -> None:
        pass

    def decide(self, obs: object, rate_features: np.ndarray | None = None) -> str:
        return "learned"


def test_the_fallback_is_reported_once_when_it_starts_and_when_the_twin_returns(
        monkeypatch: pytest.MonkeyPatch) -> None:
    import edge_mapper.policy_control as pc

    class Rule(_TwinPolicy):
        name, uses_twin = "adapt", False

    monkeypatch.setattr(pc, "make_policy",
                        lambda name: _TwinPolicy() if name.startswith("mbrl") else Rule())
    control = PolicyControl(_live(policy="mbrl", policy_checkpoint="twin.pt"))
    feed = control.feed
    assert feed is not None and control.policy is feed
    assert control.policy_name == "mbrl:twin.pt"
    feed.decide(type("Obs", (), {"slot": 0})())                 # no latent yet
    used, notes = control.decided(0)
    assert used == "adapt (fallback)" and notes[0].level == "warning"
    feed.decide(type("Obs", (), {"slot": 1})())
    assert control.decided(1) == ("adapt (fallback)", [])        # said once
    feed.offer(1, np.zeros(2), np.ones(2), 3)
    feed.decide(type("Obs", (), {"slot": 2})())
    used, notes = control.decided(2)
    assert used == "mbrl:twin.pt" and "model version 3" in notes[0].text
