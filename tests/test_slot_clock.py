"""Slots cut by frame stamps: a frame lost before the device does not shift the
slots after it, a jittering stamp stays in its slot, and a slot whose last frame never came
ends when the next slot's first frame arrives."""

from __future__ import annotations

import numpy as np
import pytest

from device_tracker.device_core import DeviceTrackerCore
from device_tracker.slot_clock import SlotClock
from twinslam.sequences.synthetic import SyntheticSequence

SLOT = 10


def test_slots_follow_stamps_not_counts() -> None:
    clock = SlotClock(SLOT, 30.0)
    stamps = 100.0 + np.arange(40) / 30.0
    assert [clock.slot_of(t) for t in stamps] == [i // SLOT for i in range(40)]
    assert [clock.is_last(t) for t in stamps] == [i % SLOT == SLOT - 1 for i in range(40)]
    # jitter of a third of a frame either way changes nothing
    jitter = stamps + np.tile([0.011, -0.011], 20)
    assert [clock.slot_of(t) for t in jitter] == [i // SLOT for i in range(40)]
    assert clock.slot_of(stamps[0] + 3.0) == 9, "a 3 s gap skips slots"
    assert clock.slot_of(stamps[0] - 1.0) == 0, "a stamp before the first is never negative"
    with pytest.raises(ValueError, match="frame_rate_hz"):
        SlotClock(SLOT, 0.0)
    with pytest.raises(ValueError, match="slot_frames"):
        SlotClock(0, 30.0)


def _play(core: DeviceTrackerCore, frames: list) -> list[tuple[int, list[int]]]:
    """Feed frames as the node does; the slots that ended, with their frame stamps (in
    frame periods)."""
    ended = []
    for f in frames:
        if core.ends_slot_before(f.stamp):
            taken = core.take_slot()
            ended.append((taken[-1].slot, [round(r.stamp * 30) for r in taken]))
        if core.track(f.color, f.depth, f.stamp).slot_done:
            taken = core.take_slot()
            ended.append((taken[-1].slot, [round(r.stamp * 30) for r in taken]))
    return ended


def test_a_lost_frame_does_not_shift_later_slots() -> None:
    seq = SyntheticSequence(4 * SLOT, seed=2)
    frames = list(seq)
    lost = {3, SLOT - 1, 2 * SLOT + 5}          # one mid-slot, one a slot's last frame
    core = DeviceTrackerCore(seq.intrinsics, SLOT, frame_rate_hz=30.0)
    ended = _play(core, [f for f in frames if f.index not in lost])
    assert [slot for slot, _ in ended] == [0, 1, 2, 3]
    for slot, stamps in ended:
        expected = [i for i in range(slot * SLOT, (slot + 1) * SLOT) if i not in lost]
        assert stamps == expected, f"slot {slot} holds the wrong frames"
    # the uploads know their slot by stamp too
    payload = core.upload(3 * SLOT - len(lost))      # frame ids count frames tracked
    assert payload is not None and payload.slot == 3


def test_a_gap_of_whole_slots_skips_them() -> None:
    seq = SyntheticSequence(5 * SLOT, seed=2)
    frames = [f for f in seq if not SLOT <= f.index < 3 * SLOT + 2]   # slots 1 and 2 gone
    core = DeviceTrackerCore(seq.intrinsics, SLOT, frame_rate_hz=30.0)
    ended = _play(core, frames)
    assert [slot for slot, _ in ended] == [0, 3, 4]
    assert ended[1][1] == list(range(3 * SLOT + 2, 4 * SLOT))
