"""``bench.edge_scaling``'s staggered fleet: devices that start at different times play the
walk's first and last slots with part of the fleet only, so its ``all on`` late share counts
the device-slots due while every device walked — and an unanswered one as late."""

from __future__ import annotations

from types import SimpleNamespace
from typing import Any

from bench.edge_scaling import EmulatedDevice, Recording, full_fleet_slots


def _device(name: str, start: float, recording: Recording,
            latencies: dict[int, float]) -> EmulatedDevice:
    device = EmulatedDevice(name, recording, start)
    stats: dict[int, Any] = {slot: SimpleNamespace(slot_latency_ms=ms)
                             for slot, ms in latencies.items()}
    device.stats = stats
    return device


def test_only_the_slots_while_every_device_walks_count_and_a_missing_answer_is_late() -> None:
    recording = Recording(summaries={k: b"" for k in range(10)}, rates={}, keyframes={},
                          slot_s=1.0)
    # a starts at 0 and walks to 10 s, b starts at 4 s: both walk from 4 to 10 s — a's slots
    # 4-9 and b's slots 0-5
    a = _device("a", 0.0, recording, {k: 1500.0 if k == 9 else 200.0 for k in range(10)})
    b = _device("b", 4.0, recording, {k: 200.0 for k in range(10) if k != 2})
    due, late = full_fleet_slots([a, b])
    assert due == 12
    assert late == 2          # a's slot 9 answered after a period, b's slot 2 never answered


def test_a_fleet_in_step_is_whole_over_the_walk_but_its_first_phases() -> None:
    recording = Recording(summaries={k: b"" for k in range(5)}, rates={}, keyframes={},
                          slot_s=1.0)
    fleet = [_device(f"d{i}", i / 4, recording, {k: 100.0 for k in range(5)})
             for i in range(4)]
    due, late = full_fleet_slots(fleet)
    # the last device starts at 0.75 s: the others' slot 0 falls before it
    assert (due, late) == (4 * 5 - 3, 0)
