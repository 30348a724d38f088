"""Scenario playback: forward then backward with stamps that keep increasing,
covered-lens bursts that keep the ground truth, and clear refusals."""

from __future__ import annotations

import numpy as np
import pytest

from twinslam.sequence_player.playback import (
    Playback,
    PlayedSequence,
    parse_bursts,
    played_device_slot,
)
from twinslam.sequences.frame import RgbdFrame, SequenceError
from twinslam.sequences.synthetic import SyntheticSequence
from twinslam.slot_protocol import default_device, table1


def test_forward_backward_revisits_every_frame_with_increasing_stamps() -> None:
    seq = SyntheticSequence(6)
    played = PlayedSequence(seq, Playback("forward_backward", parse_bursts("7:2")))
    frames = list(played)
    assert len(played) == len(frames) == 11
    names = [f.name.removesuffix(" (blanked)") for f in frames]
    assert names == [f"synthetic-{i:06d}" for i in [0, 1, 2, 3, 4, 5, 4, 3, 2, 1, 0]]
    stamps = np.array([f.stamp for f in frames])
    np.testing.assert_allclose(np.diff(stamps), 1 / 30)
    assert played.span_s == pytest.approx(10 / 30)
    assert [f.index for f in frames] == list(range(11))
    # positions 7 and 8 (frames 3 and 2 on the way back) are blank; their ground truth is not
    for f in frames:
        blank = f.index in (7, 8)
        assert (f.color.max() == 0) == blank and (f.depth.max() == 0) == blank
    np.testing.assert_array_equal(frames[7].pose, seq.pose(3))
    np.testing.assert_array_equal(frames[8].pose, seq.pose(2))


def test_backward_plays_from_the_last_frame_with_increasing_stamps() -> None:
    """A second device walking the place from the other end: frames last to first, each
    with its own ground truth, stamps running forward at the recorded period."""
    seq = SyntheticSequence(5)
    frames = list(PlayedSequence(seq, Playback("backward")))
    assert [f.name for f in frames] == [f"synthetic-{i:06d}" for i in [4, 3, 2, 1, 0]]
    assert [f.index for f in frames] == list(range(5))
    np.testing.assert_allclose(np.diff([f.stamp for f in frames]), 1 / 30)
    np.testing.assert_array_equal(frames[0].pose, seq.pose(4))


def test_forward_playback_keeps_recorded_stamps() -> None:
    seq = SyntheticSequence(4).select(1, 4)
    frames = list(PlayedSequence(seq, Playback()))
    assert [f.stamp for f in frames] == [f.stamp for f in seq]


def test_bad_scenarios_are_refused_with_the_reason() -> None:
    for bad in ("3", "a:2", "4:0", "-1:3"):
        with pytest.raises(ValueError, match="START:COUNT"):
            parse_bursts(bad)
    assert parse_bursts(" 40:5, 10:2 ") == ((10, 2), (40, 5))
    assert parse_bursts("") == ()
    with pytest.raises(ValueError, match="order must be one of"):
        Playback("sideways")

    class Forward:                        # a recording without random access, as a bag
        path, kind, entries, skipped = "run.mcap", "rosbag2", [], []
    with pytest.raises(SequenceError, match="plays forward only"):
        PlayedSequence(Forward(), Playback("forward_backward"))


def test_backward_forward_walks_back_to_the_first_frame_and_on_again() -> None:
    """A device that meets one walking from the other end and walks on: frames last to first
    and on to the last again, the turning frame once, stamps running forward."""
    seq = SyntheticSequence(4)
    played = PlayedSequence(seq, Playback("backward_forward"))
    frames = list(played)
    assert [f.name for f in frames] == [f"synthetic-{i:06d}" for i in [3, 2, 1, 0, 1, 2, 3]]
    assert [f.index for f in frames] == list(range(7)) and len(played) == 7
    np.testing.assert_allclose(np.diff([f.stamp for f in frames]), 1 / 30)
    np.testing.assert_array_equal(frames[4].pose, seq.pose(1))


def _number(frame: RgbdFrame) -> int:
    return int(frame.name.removesuffix(" (blanked)").rsplit("-", 1)[1])


@pytest.mark.parametrize("order", ["forward", "backward", "backward_forward"])
def test_two_phases_of_every_second_frame_share_no_image_and_keep_the_walks_time(
        order: str) -> None:
    """Devices replaying one walk at ``every`` 2, phases 0 and 1: one plays the sequence's
    even frames, the other its odd ones — by the frame, so a walk from the other end (8
    frames backward: its positions 0, 2, … are the odd frames 7, 5, …) still shares no image
    with a forward one —, each at its time in the whole walk (the stream path and the
    random-access one alike)."""
    seq = SyntheticSequence(8)
    whole = list(PlayedSequence(seq, Playback(order)))
    for phase in (0, 1):
        played = PlayedSequence(seq, Playback(order, every=2, phase=phase))
        frames = list(played)
        expected = [f for f in whole if _number(f) % 2 == phase]
        assert len(played) == len(frames) == len(expected)
        assert [f.index for f in frames] == list(range(len(frames)))
        assert [f.name for f in frames] == [f.name for f in expected]
        assert [f.stamp for f in frames] == pytest.approx([f.stamp for f in expected])
        assert played.span_s == pytest.approx(PlayedSequence(seq, Playback(order)).span_s)
    backward = [_number(f) for f in PlayedSequence(seq, Playback("backward", every=2, phase=1))]
    assert backward == [7, 5, 3, 1]


def test_a_blank_burst_counts_the_walks_frames_whichever_are_played() -> None:
    """A covered lens at the walk's positions 2–4 covers the frames of those positions a
    device playing one in two sees: the burst is a time of the walk, not of the camera."""
    seq = SyntheticSequence(8)
    played = list(PlayedSequence(seq, Playback("backward", parse_bursts("2:3"), every=2,
                                               phase=0)))
    # frames 6, 4, 2, 0 played, at the walk's positions 1, 3, 5, 7; 3 is in the burst
    assert [_number(f) for f in played] == [6, 4, 2, 0]
    assert [f.color.max() == 0 for f in played] == [False, True, False, False]
    np.testing.assert_array_equal(played[1].pose, seq.pose(4))


def test_a_phase_outside_every_is_refused() -> None:
    for every, phase in ((0, 0), (2, 2), (3, -1)):
        with pytest.raises(ValueError, match="phase from 0 to every - 1"):
            Playback(every=every, phase=phase)


def test_a_device_is_told_its_slot_in_the_frames_and_stamps_it_is_played() -> None:
    """Slots are cut by frame stamps: a device replayed at ``rate`` × the recorded speed sees
    its frames come ``rate`` times faster, and one playing one frame in ``every`` sees fewer
    of them; told so, its slot still spans ``slot_frames`` recorded frames. What a parameter
    file gives (as YAML's numbers or a command line's strings) stands over the defaults."""
    assert played_device_slot({}) == (default_device.SLOT_FRAMES, table1.FRAME_RATE_HZ)
    assert played_device_slot({}, rate=2.0) == (default_device.SLOT_FRAMES,
                                                2 * table1.FRAME_RATE_HZ)
    slot, rate = played_device_slot({"slot_frames": 60, "frame_rate_hz": "15"}, 3, 0.5)
    assert (slot, rate) == (20, 2.5) and slot / rate == 60 / 15 / 0.5
    with pytest.raises(ValueError, match="does not split 7 ways"):
        played_device_slot({}, 7)
    with pytest.raises(ValueError, match="rate must be a positive number"):
        played_device_slot({}, rate=0.0)
    with pytest.raises(ValueError, match="whole number of frames"):
        played_device_slot({"slot_frames": 7.5})
